"""Run nfal FMUs in non-Python hosts many times and count the crashes (docs/cosimulation.md, "Crash at exit").

Two hosts nobody here wrote the runtime for: a minimal C host (``fmus/hosts/fmi2_host.c``, what the
FMI Compliance Checker does: dlopen, instantiate, set up, step, terminate, free, dlclose, exit; and
``fmus/hosts/fmi3_host.c``, the same for FMI 3.0),
compiled with the system's C compiler, and the ``ecos`` command line that comes with the ``ecospy``
wheel (needs Debian's ``libtbb12``). Both run with nothing set up, as ``env -i PATH=/usr/bin:/bin
HOME=$HOME`` would run them (:func:`bare_environment`): the FMU's loader finds its Python itself
(fmus/loader/loader.c). A run counts as a crash when its exit code is not 0, whatever it printed.
"""

from __future__ import annotations

import csv
import os
import shutil
import stat
import subprocess
import zipfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from fmpy import read_model_description

from nfal.errors import DataFormatError, HostUnavailableError
from nfal.fmus.build import FMUS_DIR
from nfal.fmus.export_runtime import RUNTIMES, mingw_tool
from nfal.fmus.windows_python import wine_path
from nfal.cache_folder import build_once, cache_root, write_in_one_step
from nfal.models.disk_cache import digest

#: The C hosts' sources, per FMI version.
C_HOST_SOURCES = {version: FMUS_DIR / "hosts" / f"fmi{version}_host.c" for version in (2, 3)}
#: How every C host is compiled (beside the platform's libraries).
C_HOST_FLAGS = ("-O1", "-Wall")
HOST_TIMEOUT_S = 600


@dataclass
class HostRuns:
    """What N runs of one FMU or structure in one host gave."""

    exit_codes: list[int] = field(default_factory=list)
    #: {name: value} of the outputs at the stop time, per run that exited with 0.
    outputs: list[dict[str, float]] = field(default_factory=list)
    #: stdout + stderr of the first failed run ("" when none failed).
    first_failure: str = ""
    #: stdout and stderr of each run.
    texts: list[tuple[str, str]] = field(default_factory=list)

    @property
    def crashes(self) -> int:
        """Runs whose exit code was not 0 (a signal shows as a negative code)."""
        return sum(code != 0 for code in self.exit_codes)

    @property
    def signals(self) -> int:
        """Runs killed by a signal (a segmentation fault, an abort), or under wine by an unhandled exception (wine
        prints it and exits with the exception code's low byte): crashes whatever the run was meant to do."""
        return sum(code < 0 or "Unhandled exception" in err for code, (_, err) in zip(self.exit_codes, self.texts))

    def logged_once(self, needle: str, fmus: int = 1) -> int:
        """Runs whose stdout and stderr each hold ``needle`` on exactly one line per FMU (or stderr only: ecos)."""
        def once(text: str) -> bool:
            return sum(needle in line for line in text.splitlines()) == fmus
        return sum(once(err) and (once(out) or needle not in out) for out, err in self.texts)


def bare_environment(**extra: str) -> dict[str, str]:
    """Nothing set up: ``PATH=/usr/bin:/bin`` and ``HOME`` only (as ``env -i``), plus ``extra`` (e.g.
    ``NFAL_FMU_PYTHON``, or a ``PATH`` with another Python first)."""
    return {"PATH": "/usr/bin:/bin", "HOME": os.environ.get("HOME", "/"), **extra}


def compile_c_host(out_dir: Path, fmi_version: int = 2, *, windows: bool = False) -> Path:
    """Compile ``fmus/hosts/fmi<fmi_version>_host.c`` into ``out_dir`` (made if missing); return the executable
    (``windows``: a win64 ``.exe``, with mingw-w64, run under wine by :mod:`nfal.apps.wine`). Compiled once per
    source (the headers beside it included), compiler and command line into the nfal cache
    (:func:`~nfal.cache_folder.cache_root`), and copied from there; where the cache cannot be written, into
    ``out_dir`` directly."""
    source = C_HOST_SOURCES[fmi_version]
    if windows:
        compiler, flags, name = mingw_tool("gcc"), ("-static",), f"{source.stem}.exe"
    else:
        compiler, flags, name = shutil.which("cc") or shutil.which("gcc"), ("-ldl", "-pthread"), source.stem
        if compiler is None:
            raise HostUnavailableError("the C host needs a C compiler: apt-get install gcc")
    executable = Path(out_dir) / name
    executable.parent.mkdir(parents=True, exist_ok=True)  # else the copy fails, and then cc on a folder not there

    def compile_to(path: Path) -> None:
        subprocess.run([compiler, *C_HOST_FLAGS, "-o", str(path), str(source), *flags], check=True,
                       capture_output=True, text=True)

    binary = Path(compiler).resolve()
    headers = sorted(source.parent.glob("*.h"))
    key = digest(source.read_bytes(), *(h.read_bytes() for h in headers), str(binary), binary.stat().st_size,
                 binary.stat().st_mtime_ns, C_HOST_FLAGS, flags)
    cached = cache_root() / "c-hosts" / key / name

    try:
        build_once(cached.is_file, cached.parent.with_name(f"{key}.lock"),
                   lambda: write_in_one_step(cached, compile_to))
        shutil.copy2(cached, executable)
    except OSError:  # the cache cannot be written
        compile_to(executable)
    return executable


def _c_host_command(host: Path, folder: Path, strings: dict[str, str]) -> tuple[list[str], dict[str, str], list[str]]:
    """The C host's command line for the FMU extracted to ``folder`` (up to the stop time), {value reference:
    name} of its Real (Float64) outputs, and the ``VR=TEXT`` arguments that set the String variables
    ``strings`` before initialisation (FMI 2.0 host only). The host must be the FMU's FMI version's; a Windows
    one (``.exe``) is given the win64 binary and Windows paths (wine's)."""
    description = read_model_description(str(folder))
    references = {v.name: v.valueReference for v in description.modelVariables if v.type == "String"}
    if set(strings) - set(references):
        raise KeyError(f"no String variables {sorted(set(strings) - set(references))} in {folder.name}")
    version = int(description.fmiVersion[0])
    if strings and version != 2:
        raise HostUnavailableError("only the FMI 2.0 C host sets String variables")
    if host.stem != C_HOST_SOURCES[version].stem:
        raise HostUnavailableError(f"{folder.name} is FMI {description.fmiVersion}: run it in "
                                   f"{C_HOST_SOURCES[version].stem}, not {host.name}")
    outputs = {str(v.valueReference): v.name for v in description.modelVariables
               if v.causality == "output" and v.type in ("Real", "Float64")}
    model = description.coSimulation.modelIdentifier
    settings = [f"{references[name]}={value}" for name, value in strings.items()]
    # FMI 2.0 passes the resources as a file URI, FMI 3.0 as a path ending in a separator
    if host.suffix == ".exe":
        binary = wine_path(folder / "binaries" / RUNTIMES[version].windows_platform / f"{model}.dll")
        resources = wine_path(folder / "resources")
        resources = "file:///" + resources.replace("\\", "/") if version == 2 else resources + "\\"
        return [str(host.resolve()), binary, description.guid, resources], outputs, settings
    binary = folder / "binaries" / RUNTIMES[version].platform / f"{model}.so"
    resources = (folder / "resources").as_uri() if version == 2 else f"{folder / 'resources'}{os.sep}"
    return [str(host.resolve()), str(binary), description.guid, resources], outputs, settings


def _run(command: list[str], cwd: Path, env: dict[str, str] | None) -> subprocess.CompletedProcess:
    # pipes, never files, for the std handles: under wine a Python with a file for one dies (nfal/apps/wine.py)
    return subprocess.run(command, cwd=cwd, env=bare_environment() if env is None else env, capture_output=True,
                          stdin=subprocess.DEVNULL, text=True, timeout=HOST_TIMEOUT_S)


def run_in_c_host(host: Path, fmu: Path, work_dir: Path, *, runs: int, stop_time: float = 0.01,
                  step_size: float = 5e-4, workers: int = 2, runtime: Path | None = None,
                  strings: dict[str, str] | None = None, env: dict[str, str] | None = None,
                  cwd: Path | None = None, wrapper: tuple[str, ...] = ()) -> HostRuns:
    """Run ``fmu`` ``runs`` times in the C host of its FMI version (:func:`compile_c_host`) from its default
    start values; read every Real (Float64) output.

    ``runtime``: a library to run in place of the FMU's binary (e.g. pythonfmu's stock one, to compare);
    ``strings``: String parameters to set first, by name (FMI 2.0), e.g. ``{"port": ...}`` for the HardwareProxy;
    ``workers``: runs at a time after the first (1 for an FMU that holds a device);
    ``env``: the host's environment (default :func:`bare_environment`); ``cwd``: its working directory
    (default: the extracted FMU's folder); ``wrapper``: a command to run the host under (e.g. valgrind's).
    """
    folder = Path(work_dir) / fmu.stem
    with zipfile.ZipFile(fmu) as archive:
        archive.extractall(folder)
    command, outputs, settings = _c_host_command(Path(host), folder, strings or {})
    if runtime is not None:
        shutil.copy2(runtime, command[1])
    command = [*wrapper, *command, repr(stop_time), repr(step_size), *outputs, *settings]
    where = folder if cwd is None else cwd
    first = _run(command, where, env)  # alone: it fills numba's on-disk cache (models/numba_cache.py)
    with ThreadPoolExecutor(max_workers=workers) as pool:
        done = [first, *pool.map(lambda _: _run(command, where, env), range(runs - 1))]
    result = HostRuns()
    for run in done:
        result.exit_codes.append(run.returncode)
        result.texts.append((run.stdout, run.stderr))
        if run.returncode == 0:
            pairs = (line.split("=", 1) for line in run.stdout.splitlines() if "=" in line and line[0].isdigit())
            result.outputs.append({outputs[vr]: float(value) for vr, value in pairs})
        elif not result.first_failure:
            result.first_failure = run.stdout + run.stderr
    return result


def ecos_executable(cache_dir: Path) -> Path:
    """The ``ecos`` command line of the installed ecospy wheel, copied to ``cache_dir`` with its exec bit set
    (the wheel ships it without)."""
    try:
        import ecospy  # noqa: F401 - on use: optional (the test extra); loads libecosc, fails without libtbb12
    except ImportError as exc:
        raise HostUnavailableError("ecos needs the ecospy package: pip install ecospy") from exc
    except OSError as exc:
        raise HostUnavailableError(f"ecos needs Debian's libtbb12: apt-get install libtbb12 ({exc})") from exc
    binaries = Path(ecospy.__file__).resolve().parent / "binaries"
    target = Path(cache_dir) / "ecos"
    target.mkdir(parents=True, exist_ok=True)
    for name in ("ecos", "proxyfmu", "libecosc.so"):
        shutil.copy2(binaries / name, target / name)
        (target / name).chmod((target / name).stat().st_mode | stat.S_IXUSR)
    return target / "ecos"


#: How much of the start and of the end of what ecos said an error quotes (all of it is in the run's ecos.log).
QUOTED_CHARS = 2000


def run_in_ecos(ecos: Path, ssp: Path, work_dir: Path, *, runs: int, stop_time: float,
                step_size: float = 5e-4, env: dict[str, str] | None = None,
                wrapper: tuple[str, ...] = ()) -> HostRuns:
    """Simulate ``ssp`` (an SSP archive, or one FMU alone: FMI 2.0 or 3.0) ``runs`` times with ``ecos simulate``
    (in ``env``, default :func:`bare_environment`; ``ecos.exe`` under ``wrapper``, wine, gets the Windows path);
    ``outputs`` holds each run's CSV columns."""
    result = HostRuns()
    path = wine_path(ssp) if Path(ecos).suffix == ".exe" else str(ssp)
    for k in range(runs):
        folder = Path(work_dir) / f"ecos_{k}"
        folder.mkdir(parents=True)
        run = _run([*wrapper, str(ecos), "simulate", "--path", path, "--stopTime", repr(stop_time), "--stepSize",
                    repr(step_size)], folder, env)
        result.exit_codes.append(run.returncode)
        result.texts.append((run.stdout, run.stderr))
        said, log = run.stdout + run.stderr, folder / "ecos.log"
        log.write_text(said, encoding="utf-8")
        if run.returncode == 0:
            written = folder / f"{ssp.stem}.csv"
            if not written.is_file():  # seen twice: ecos.exe under wine beside a loaded machine, a null read in it
                raise DataFormatError(f"ecos exited with 0 but wrote no {written.name}; all it said is in {log}; "
                                      + (f"it said: {said}" if len(said) <= 2 * QUOTED_CHARS else
                                         f"it began: {said[:QUOTED_CHARS]}\n[...]\nand ended: {said[-QUOTED_CHARS:]}"))
            result.outputs.append(read_ecos_csv(written))
        elif not result.first_failure:
            result.first_failure = said
    return result


def fmus_in(archive: Path) -> int:
    """How many FMUs the SSP ``archive`` holds."""
    with zipfile.ZipFile(archive) as ssp:
        return sum(name.endswith(".fmu") for name in ssp.namelist())


def read_ecos_csv(path: Path) -> dict[str, list[float]]:
    """ecos's CSV as {"Element::variable": values} for its Real columns (written with 6 decimals)."""
    with open(path, newline="", encoding="utf-8") as handle:
        rows = list(csv.reader(handle, skipinitialspace=True))
    header = [name.strip() for name in rows[0]]
    columns = {name.removesuffix("[REAL]"): i for i, name in enumerate(header)
               if name.endswith("[REAL]") or name == "time"}
    return {name: [float(row[i]) for row in rows[1:] if row] for name, i in columns.items()}
