"""The Windows test bench: Windows hosts run nfal's win64 FMUs under wine (docs/cosimulation.md, "Windows").

:func:`wine_bench` makes a wine prefix of nfal's own (in the user's cache, never ``~/.wine``) and returns what a
Windows host needs to run in it: the environment (nothing else set up: ``PATH=/usr/bin:/bin``, ``HOME`` and
wine's own variables), the command prefix (``wine``) and the Windows path of a Linux file. Two stand-ins make
wine 8.0 (Debian 12's) a Windows that these hosts and packages run on; neither goes into an FMU:

* ``tar``: Windows 10 and later ship ``tar.exe`` (bsdtar) in System32, and ecos unpacks every FMU and SSP
  with ``tar -xf ARCHIVE -C DIR``; wine has none. The prefix's ``tar.exe`` (``fmus/hosts/wine_tar.c``) does the
  same with the Windows Python's ``zipfile``.
* C99 complex functions: wine 8.0's ucrtbase leaves ``cexp``, ``carg``, ``csin``, ``ccos``, ``ctan``, their
  hyperbolic forms and ``cpow`` unimplemented (a call aborts the process; measured through numpy and
  scipy.signal, which the Controller and SensorChain FMUs use). The prefix's ``ucrtbase.dll``
  (``fmus/hosts/wine_ucrtbase.c``) implements the UCRT's complex math functions with mingw-w64's and forwards
  each other export to wine's own ucrtbase (copied beside it as ``ucrtbase_wine.dll``).

FMPy's remoting server (``server_tcp.exe``, FMI 2.0) watches a lock file its Linux client holds, and exits as soon
as it can open it; under wine the client's hold is invisible, so the server quit 0.5 s after it started. The
``wine64`` that :func:`run_in_fmpy_remoting` puts first on PATH drops that argument; the client still ends the
server when it is done.

Windows' own std handles differ too: a Python started by wine 8.0 with a regular file as stdin or stdout dies
("init_sys_streams: Invalid handle"), so hosts run with pipes (as :mod:`nfal.apps.host_check` runs them).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

from nfal.errors import HostUnavailableError, RuntimeBuildError
from nfal.fmus.build import FMUS_DIR
from nfal.fmus.export_runtime import dll_exports, mingw_tool
from nfal.fmus.windows_python import wine_path
from nfal.apps.host_check import HostRuns
from nfal.cache_folder import cache_root, exclusive, write_in_one_step

#: wine's own PE build of ucrtbase (Debian's wine64 8.0).
WINE_WINDOWS_DLLS = Path("/usr/lib/x86_64-linux-gnu/wine/x86_64-windows")
UCRTBASE_SHIM = FMUS_DIR / "hosts" / "wine_ucrtbase.c"
TAR_SHIM = FMUS_DIR / "hosts" / "wine_tar.c"
#: The MSVC runtime DLLs ecos.exe needs (a Windows user has them from the Visual C++ redistributable; here they come
#: from the Windows Python, which ships them).
MSVC_RUNTIME = ("msvcp140.dll", "msvcp140_atomic_wait.dll", "vcruntime140.dll", "vcruntime140_1.dll")
WINE_TIMEOUT_S = 600
#: How long the prefix's wineserver (and wine's services with it) outlive the last Windows process: :func:`wine_bench`.
SERVER_LINGER_S = 30


@dataclass(frozen=True)
class WineBench:
    """A wine prefix ready for Windows hosts: run ``[*command, host.exe, ...]`` in ``environment``."""

    prefix: Path
    python_root: Path
    environment: dict[str, str] = field(default_factory=dict)

    @property
    def command(self) -> tuple[str, ...]:
        return ("wine",)


def wine_bench(python_root: Path, prefix: Path | None = None) -> WineBench:
    """The wine prefix ``prefix`` (default: nfal's, in the user's cache), made on first use (wineboot, ~20 s) and
    given the two stand-ins of this module; ``python_root`` is the Windows Python whose ``zipfile`` unpacks."""
    if shutil.which("wine") is None:
        raise HostUnavailableError("the Windows bench needs wine: apt-get install wine wine64")
    prefix = Path(prefix) if prefix else cache_root() / "wine-prefix"
    environment = {"PATH": "/usr/bin:/bin", "HOME": os.environ.get("HOME", "/"), "WINEPREFIX": str(prefix),
                   "WINEDEBUG": "-all", "WINEDLLOVERRIDES": "ucrtbase=n,b"}
    system32 = prefix / "drive_c" / "windows" / "system32"
    with exclusive(prefix.with_name(prefix.name + ".lock")):  # one process sets the prefix up at a time
        if not (system32 / "kernel32.dll").is_file():
            prefix.mkdir(parents=True, exist_ok=True)
            _wine(["wine", "wineboot", "--init"], environment, "making the wine prefix")
        python = wine_path(Path(python_root) / "python.exe").replace("\\", "\\\\")
        _compile(["gcc", "-O1", "-Wall", "-Werror", f'-DNFAL_PYTHON="{python}"', "-static", str(TAR_SHIM)],
                 system32 / "tar.exe")
        _install_ucrtbase(system32)
        _start_server(environment)
    return WineBench(prefix, Path(python_root), environment)


def _start_server(environment: dict[str, str]) -> None:
    """Start the prefix's wineserver to linger :data:`SERVER_LINGER_S` after the last process, and wine's services
    with nothing of ours open. Otherwise the first Windows process of each burst starts them: they inherit its
    stdout and stderr pipes and hold them until the server's default 3 s linger ends, so every host run whose
    output is read to the end took 3 s longer (measured: ``wine cmd /c echo`` 2.9 s, 0.24 s with this). A server
    that is already up is kept as it is."""
    quiet = {"env": environment, "stdin": subprocess.DEVNULL, "stdout": subprocess.DEVNULL,
             "stderr": subprocess.DEVNULL, "timeout": WINE_TIMEOUT_S}
    subprocess.run(["wineserver", f"-p{SERVER_LINGER_S}"], **quiet)
    subprocess.run(["wine", "cmd", "/c", "exit"], **quiet)


def _wine(command: list[str], environment: dict[str, str], what: str) -> None:
    done = subprocess.run(command, env=environment, stdin=subprocess.DEVNULL, capture_output=True, text=True,
                          timeout=WINE_TIMEOUT_S)
    if done.returncode != 0:
        raise HostUnavailableError(f"{what} failed: {(done.stdout + done.stderr)[-1000:]}")


def _compile(command: list[str], target: Path) -> None:
    """Run mingw-w64's ``command[0]`` on the rest into ``target``, replaced in one step (a wine process may have the
    old one loaded); an error with the compiler's words if it fails."""
    def compile_to(partial: Path) -> None:
        try:
            done = subprocess.run([mingw_tool(command[0]), *command[1:], "-o", str(partial)], capture_output=True,
                                  text=True, timeout=WINE_TIMEOUT_S)
        except RuntimeBuildError as exc:
            raise HostUnavailableError(str(exc)) from exc
        if done.returncode != 0:
            raise HostUnavailableError(f"compiling the wine bench's {target.name} failed:\n"
                                       f"{(done.stdout + done.stderr)[-2000:]}")

    write_in_one_step(target, compile_to)


def _install_ucrtbase(system32: Path) -> None:
    """Build the complex-function ucrtbase (once per source) into ``system32``, wine's own beside it."""
    wine_own = WINE_WINDOWS_DLLS / "ucrtbase.dll"
    if not wine_own.is_file():
        raise HostUnavailableError(f"no {wine_own}: the Windows bench needs Debian's wine64 (8.0)")
    stamp = system32 / "ucrtbase.nfal"
    # the shim's source, wine's DLL it forwards to, and this module (the .def's generator)
    key = hashlib.sha256(UCRTBASE_SHIM.read_bytes() + wine_own.read_bytes() + Path(__file__).read_bytes()).hexdigest()
    if stamp.is_file() and stamp.read_text() == key:
        return
    exports = dll_exports(wine_own)
    source = UCRTBASE_SHIM.read_text(encoding="utf-8")
    ours = set(re.findall(r"\bnfal_(\w+)\(", source))
    for family in re.findall(r"^(?:COMPLEX|REAL)\((\w+)\)", source, re.M):
        ours |= {family, f"{family}f", f"{family}l"}
    definition = system32 / "ucrtbase_nfal.def"
    definition.write_text("LIBRARY ucrtbase.dll\nEXPORTS\n" + "".join(
        f"    {name}=nfal_{name}\n" if name in ours else f"    {name}=ucrtbase_wine.{name}\n" for name in exports))
    write_in_one_step(system32 / "ucrtbase_wine.dll", lambda partial: shutil.copy2(wine_own, partial))
    _compile(["gcc", "-O2", "-Wall", "-Werror", "-shared", "-s", str(UCRTBASE_SHIM), str(definition), "-static"],
             system32 / "ucrtbase.dll")
    stamp.write_text(key)


def ecos_windows(bench: WineBench, cache_dir: Path) -> Path:
    """ecos.exe of the installed ecospy wheel (which ships the Windows build beside the Linux one), with
    libecosc.dll, proxyfmu.exe and the MSVC runtime it needs, copied to ``cache_dir``/ecos-win64."""
    try:
        import ecospy  # noqa: F401 - on use: optional (the test extra); loads libecosc, fails without libtbb12
    except (ImportError, OSError) as exc:
        raise HostUnavailableError(f"ecos.exe comes with the ecospy package: pip install ecospy ({exc})") from exc
    binaries = Path(ecospy.__file__).resolve().parent / "binaries"
    missing = [name for name in MSVC_RUNTIME if not (bench.python_root / name).is_file()]
    if missing:
        raise HostUnavailableError(f"ecos.exe needs the MSVC runtime ({', '.join(missing)}), which the Windows Python "
                                   f"{bench.python_root} does not have beside it")
    target = Path(cache_dir) / "ecos-win64"
    target.mkdir(parents=True, exist_ok=True)
    for source in [binaries / "ecos.exe", binaries / "libecosc.dll", binaries / "proxyfmu.exe",
                   *(bench.python_root / name for name in MSVC_RUNTIME)]:
        shutil.copy2(source, target / source.name)
    return target / "ecos.exe"


#: Run by :func:`run_in_fmpy_remoting` in a Python of its own: FMPy simulates the FMU through its remoting server.
_FMPY_REMOTE = """
import json, sys
from fmpy import simulate_fmu
result = simulate_fmu(sys.argv[1], stop_time=float(sys.argv[2]), step_size=5e-4, output_interval=5e-4,
                      remote_platform="win64")
print("NFAL_OUTPUTS=" + json.dumps({name: float(result[name][-1]) for name in result.dtype.names if name != "time"}))
"""


def run_in_fmpy_remoting(bench: WineBench, fmu: Path, work_dir: Path, *, runs: int, stop_time: float) -> HostRuns:
    """Simulate the FMI 2.0 ``fmu`` ``runs`` times in FMPy's remoting server for win64 (``server_tcp.exe`` under
    wine, FMPy's own client on Linux), from a copy without its Linux binaries (FMPy remotes only an FMU that does
    not support the host); ``outputs`` holds each run's outputs at the stop time."""
    work_dir = Path(work_dir)
    work_dir.mkdir(parents=True, exist_ok=True)
    windows_only = work_dir / fmu.name
    with zipfile.ZipFile(fmu) as source, zipfile.ZipFile(windows_only, "w", zipfile.ZIP_DEFLATED) as target:
        for item in source.infolist():
            if not item.filename.startswith("binaries/linux64/"):
                target.writestr(item, source.read(item))
    wrappers = bench.prefix / "nfal-bin"
    wrappers.mkdir(exist_ok=True)
    (wrappers / "wine64").write_text('#!/bin/sh\n# nfal/apps/wine.py: FMPy remoting without its lock file\n'
                                     f'exec {shutil.which("wine")} "$1" "$2"\n')
    (wrappers / "wine64").chmod(0o755)
    environment = {**bench.environment, "PATH": f"{wrappers}:{bench.environment['PATH']}"}
    result = HostRuns()
    for _ in range(runs):
        done = subprocess.run([sys.executable, "-c", _FMPY_REMOTE, str(windows_only), repr(stop_time)],
                              env=environment, cwd=work_dir, stdin=subprocess.DEVNULL, capture_output=True, text=True,
                              timeout=WINE_TIMEOUT_S)
        result.exit_codes.append(done.returncode)
        result.texts.append((done.stdout, done.stderr))
        line = next((line for line in done.stdout.splitlines() if line.startswith("NFAL_OUTPUTS=")), None)
        if done.returncode == 0 and line:
            result.outputs.append(json.loads(line.split("=", 1)[1]))
        elif not result.first_failure:
            result.first_failure = done.stdout + done.stderr
    return result
