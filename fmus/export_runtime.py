"""The FMI binaries nfal FMUs ship: pythonfmu's and pythonfmu3's C++ export runtimes, patched, built from source.

The prebuilt runtimes of pythonfmu 0.7.0 (FMI 2.0) and pythonfmu3 0.3.4 (FMI 3.0) crash non-Python
hosts at exit and answer every Python exception with a fatal status (docs/cosimulation.md, "Crash at
exit"). :data:`RUNTIMES` holds their sources, one folder each, with the fixes marked ``// nfal:``:

* ``fmus/runtime/``: NTNU-IHB/PythonFMU 6e6f489 (= pythonfmu 0.7.0, MIT), FMI 2.0;
* ``fmus/runtime3/``: StephenSmith25/PythonFMU3 6c4b81c (= pythonfmu3 0.3.4, MIT; its ``cppfmu/`` is
  SINTEF Ocean's cppfmu, MPL-2.0), FMI 3.0.

In both, the interpreter is never finalised (``PyState.hpp``); a Python exception is answered with an
error status (not fatal) and its ``str()`` as the one logged line, and leaves the instance whole
(``handle_py_exception``); errors reach the host's logger even when logging is off; each instance
imports its own slave module; the ``PyState`` pointer is never destroyed by ``exit()``, so the library's
destructor does not release it a second time (a host aborted at exit, "corrupted double-linked list"); a thread
of the host keeps its Python thread state from one call to the next (``py_safe_run``: a new one per call was a
quarter of ecos's CPU).
FMI 2.0 only: the slave module's borrowed ``__dict__`` is no longer released (``findClass``), ``%`` is
escaped (the FMI 2.0 logger takes a printf format; FMI 3.0's does not), and a second ``fmi2FreeInstance``
of an instance does nothing (``fmi2.cpp`` keeps the set of live instances). FMI 3.0 only: the log queue is
read after the exception is taken (it was read with the exception pending: SIGSEGV), an import failure is no
longer printed away before it is reported, a NULL logger callback is allowed, two leaks are closed, a
failed reset leaves no dangling references, and the start and stop time of ``fmi3EnterInitializationMode`` reach the
slave (they were dropped).

:func:`runtime_library` builds one with CMake for the running Python (once; the result is cached by
the hash of the sources) and :mod:`nfal.fmus.build` puts it into every FMU as ``<model>_runtime.so``.

In front of it, as the binary a host loads (``<model>.so``), goes the loader (``fmus/loader/loader.c``,
:func:`loader_library`): it has no Python symbols, starts the Python the FMU recorded in
``resources/python.cfg`` (:func:`python_settings`, :func:`python_config`; the override
:data:`PYTHON_OVERRIDE_ENV`) and forwards every FMI function the runtime exports (generated from the FMI
headers, :func:`fmi_functions`, :func:`forwarders_source`). docs/cosimulation.md, "The loader".
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cmake

from nfal.errors import RuntimeBuildError
from nfal.fmus.runtime_upstream import tree_files
from nfal.fmus.windows_python import check_windows_python
from nfal.cache_folder import build_once, cache_root

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Runtime:
    """One vendored runtime: its CMake source folder and where its binary goes inside an FMU."""

    #: The vendored, patched sources (a CMake project).
    sources: Path
    #: The platform folder CMake builds it into, which is also its folder inside an FMU
    #: (``binaries/<platform>/<model>.so``; FMI 2.0 and FMI 3.0 name the platform differently).
    platform: str
    #: The cache folder's name (``~/.cache/nfal/<cache_name>/<hash>/``).
    cache_name: str
    #: The FMI version (the loader is compiled for it).
    fmi_version: int
    #: Its platform folder for 64-bit Windows (the FMI standard's name).
    windows_platform: str

    def source_files(self) -> list[Path]:
        """The runtime's sources, the value cache both runtimes include, and the loader's (the FMU's binaries are
        built from them)."""
        return [self.sources / name for name in tree_files(self.sources)] + [VALUE_CACHE_HEADER, LOADER_SOURCE]

    @property
    def function_types(self) -> Path:
        """The FMI header with one ``typedef <return> <name>TYPE(<parameters>);`` per function."""
        name = "fmi2FunctionTypes.h" if self.fmi_version == 2 else "fmi3FunctionTypes.h"
        return self.sources / "src" / "fmi" / name


_HERE = Path(__file__).resolve().parent
#: The loader every FMU's binary is (fmus/loader/loader.c; on Windows with fmus/loader/loader_windows.h).
LOADER_SOURCE = _HERE / "loader" / "loader.c"
LOADER_WINDOWS_HEADER = _HERE / "loader" / "loader_windows.h"
#: nfal's value cache (docs/cosimulation.md), a header both runtimes include (their CMakeLists name its folder).
VALUE_CACHE_HEADER = _HERE / "value_cache" / "nfal_value_cache.hpp"
#: FMI version -> its runtime.
RUNTIMES: dict[int, Runtime] = {
    2: Runtime(_HERE / "runtime", "linux64", "pythonfmu-export", 2, "win64"),
    3: Runtime(_HERE / "runtime3", "x86_64-linux", "pythonfmu3-export", 3, "x86_64-windows"),
}
#: The library CMake builds (the FMU's copy is ``binaries/<platform>/<model>_runtime.so``).
LIBRARY_NAME = "libpythonfmu-export.so"
#: The loader, built beside it (the FMU's copy is ``binaries/<platform>/<model>.so``).
LOADER_NAME = "nfal-loader.so"
#: Changed whenever forwarders_source changes what it writes (part of the loader's cache key).
_GENERATOR_VERSION = b"2"
#: What the FMU's runtime is called beside the loader: ``<model>`` + this.
RUNTIME_SUFFIX = "_runtime.so"
#: The file in the FMU's resources that names its Python (:func:`python_settings`; read by the loader).
PYTHON_CONFIG = "python.cfg"
#: Its counterpart for the Windows binaries (a Windows Python: fmus/windows_python.py).
WINDOWS_PYTHON_CONFIG = "python-win64.cfg"
#: The environment variable that overrides it (a Python executable).
PYTHON_OVERRIDE_ENV = "NFAL_FMU_PYTHON"
BUILD_TIMEOUT_S = 600
#: CMake from its PyPI package (an install requirement), not whichever cmake PATH finds first: the runtime's
#: CMakeLists.txt builds on Python's stable ABI only with CMake 3.26 or newer (Debian 12's 3.25 built it on the
#: full API, and the cache kept whichever came first).
CMAKE = str(Path(cmake.CMAKE_BIN_DIR) / "cmake")
#: The lock file beside each cached build: one process builds it, the others wait (cache_folder.exclusive).
BUILD_LOCK = ".build.lock"

#: Prints a Python's settings as ``key=value`` lines: the build runs it in the Python that builds the
#: FMU (recorded in resources/python.cfg), the loader in an override's Python. Standard library only.
PYTHON_INFO = r"""
import os, site, sys, sysconfig
get = sysconfig.get_config_var
def libpython():
    if os.name == "nt":
        name = "python%d%d.dll" % sys.version_info[:2]
        for folder in (sys.base_prefix, os.path.dirname(sys.executable)):
            if os.path.isfile(os.path.join(folder, name)):
                return os.path.join(folder, name)
        return ""
    names = [n for n in (get("INSTSONAME"), get("LDLIBRARY")) if n and ".so" in n]
    folders = [f for f in (get("LIBDIR"), get("LIBPL"), os.path.join(sys.base_prefix, "lib")) if f]
    if get("LIBDIR") and get("MULTIARCH"):
        folders.append(os.path.join(get("LIBDIR"), get("MULTIARCH")))
    for folder in folders:
        for name in names:
            if os.path.isfile(os.path.join(folder, name)):
                return os.path.join(folder, name)
    return ""
paths = list(site.getsitepackages())
if site.ENABLE_USER_SITE:
    paths.append(site.getusersitepackages())
paths += [sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]]
paths = [p for i, p in enumerate(paths) if os.path.isdir(p) and p not in paths[:i]]
print("executable=" + sys.executable)
print("version=%d.%d" % sys.version_info[:2])
print("prefix=" + sys.prefix)
print("base_prefix=" + sys.base_prefix)
print("libpython=" + libpython())
print("site=" + os.pathsep.join(paths))
"""


def python_settings(executable: str | os.PathLike | None = None) -> dict[str, str]:
    """The settings of the Python ``executable`` (default: this one) that an FMU records: executable,
    version, prefix, base_prefix, libpython ("" without a shared one), site (``os.pathsep``-joined)."""
    if executable is None:
        return dict(_this_pythons_settings())
    done = subprocess.run([str(executable), "-c", PYTHON_INFO], capture_output=True, text=True, timeout=60)
    if done.returncode != 0:
        raise RuntimeBuildError(f"cannot read the settings of the Python {executable}: {done.stderr.strip()[-500:]}")
    return dict(line.split("=", 1) for line in done.stdout.splitlines() if "=" in line)


@functools.cache
def _this_pythons_settings() -> dict[str, str]:
    """This interpreter's settings, asked once per process: every FMU a build packs records them, and asking is a
    subprocess (seven in a build of every FMU)."""
    return python_settings(sys.executable)


def python_config(settings: dict[str, str], *, windows: bool = False) -> str:
    """The text of an FMU's ``resources/python.cfg`` (``windows``: ``python-win64.cfg``, read by the Windows
    binaries) for ``settings`` (:func:`python_settings`)."""
    binary, library = ("<Model>.dll", "pythonXY.dll beside its python.exe") if windows else ("<Model>.so",
                                                                                             "shared libpython")
    lines = ["# The Python this FMU runs in a host that has none loaded (written by nfal build; read by the",
             f"# loader, binaries/<platform>/{binary}). To run it with another Python, set override= to that",
             f"# Python's executable, or the environment variable {PYTHON_OVERRIDE_ENV} (which wins): it needs a",
             f"# {library} and this FMU's packages (numpy, scipy, numba, control; pyserial, cobs for",
             "# the HardwareProxy)."]
    if not windows:
        check = "import sysconfig; print(sysconfig.get_config_var('Py_ENABLE_SHARED'))"
        lines += ["# Check a Python with:", f"#   python -c \"{check}\"   (1: shared)"]
    lines += ["override="]
    lines += [f"{key}={settings.get(key, '')}" for key in ("executable", "version", "prefix", "base_prefix",
                                                             "libpython", "site")]
    return "\n".join(lines) + "\n"


#: One FMI function: its return type, name, and parameters as (declaration, argument name).
_TYPEDEF = re.compile(r"typedef\s+([\w\s\*]+?)\s*\b(fmi[23]\w+)TYPE\s*\(([^;]*?)\)\s*;", re.S)
_TYPE_WORDS = re.compile(r"^(fmi[23]\w+|size_t|void|char|int|double|unsigned|const)$")


def fmi_functions(header: str) -> list[tuple[str, str, list[tuple[str, str]]]]:
    """Every function of an FMI ``*FunctionTypes.h`` text: (return type, name, [(declaration, argument)]).

    FMI 2.0's typedefs give types only (arguments are named ``a0``, ``a1``, ...), FMI 3.0's give names."""
    text = re.sub(r"/\*.*?\*/", "", header, flags=re.S)
    functions = []
    for returns, name, parameters in _TYPEDEF.findall(text):
        declared = []
        parts = [" ".join(p.split()) for p in parameters.split(",")]
        for k, part in enumerate(p for p in parts if p and p != "void"):
            words = re.findall(r"\w+", part)
            if _TYPE_WORDS.match(words[-1]):  # no name given: add one
                argument = f"a{k}"
                part = part.replace("[]", f" {argument}[]") if "[]" in part else f"{part} {argument}"
            else:
                argument = words[-1]
            declared.append((part, argument))
        functions.append((" ".join(returns.split()), name, declared))
    return functions


def _failure_value(returns: str, fmi_version: int) -> str:
    if returns == "void":
        return ""
    if returns.endswith("Status"):
        return f" fmi{fmi_version}Error"
    return " NULL"


#: What a getter with pointer outputs answers for an instance that is not live, besides its error: empty
#: values (ecos 0.7.2 reads a String output of an instance whose instantiation failed, ignoring the error).
_POINTER_OUTPUTS = {
    "fmi2GetString": "for (size_t k = 0; a3 && k < a2; ++k) a3[k] = \"\";",
    "fmi3GetString": "for (size_t k = 0; values && k < nValues; ++k) values[k] = \"\";",
    "fmi3GetBinary": "for (size_t k = 0; values && valueSizes && k < nValues; ++k) "
                     "{ values[k] = NULL; valueSizes[k] = 0; }",
}


def forwarders_source(functions, exported: set[str], fmi_version: int) -> str:
    """C source (``nfal_forwarders.h``) of the loader's function table and one exported forwarder per
    function of ``functions`` (:func:`fmi_functions`) that the runtime exports (``exported``)."""
    chosen = [f for f in functions if f[1] in exported]
    lines = ["/* Generated by fmus/export_runtime.py (forwarders_source) from the FMI headers: do not edit. */",
             "static struct {"]
    lines += [f"    {name}TYPE *{name};" for _, name, _ in chosen]
    lines += ["} nfal_table;", "", "static void nfal_fill_table(void)", "{"]
    lines += [f'    nfal_table.{name} = ({name}TYPE *)nfal_runtime_symbol("{name}");' for _, name, _ in chosen]
    lines += ["}", ""]
    constants = {"fmi2GetVersion": "fmi2Version", "fmi2GetTypesPlatform": "fmi2TypesPlatform",
                 "fmi3GetVersion": "fmi3Version"}
    for returns, name, parameters in chosen:
        declaration = ", ".join(d for d, _ in parameters) or "void"
        arguments = ", ".join(a for _, a in parameters)
        fail = _failure_value(returns, fmi_version)
        lines += [f"{returns} {name}({declaration})", "{"]
        if name in constants:  # answered without Python
            lines += [f"    return {constants[name]};", "}", ""]
            continue
        first = parameters[0][1] if parameters else None
        if "Instantiate" in name:
            if fmi_version == 2:
                failure = "nfal_log_failure(a0, a4, message);"
            else:
                failure = "nfal_log_failure(instanceName, instanceEnvironment, logMessage, message);"
            lines += ["    char message[NFAL_MESSAGE_SIZE];",
                      "    if (!nfal_load(message, sizeof message)) {", f"        {failure}", "        return NULL;",
                      "    }", f"    if (!nfal_table.{name}) return NULL;",
                      f"    {returns} instance = nfal_table.{name}({arguments});",
                      "    if (instance) nfal_live_add(instance);", "    return instance;", "}", ""]
            continue
        if "FreeInstance" in name:
            lines += [f"    if (nfal_live_remove({first})) nfal_table.{name}({first});", "}", ""]
            continue
        guard = f"nfal_live_has({first})" if first in ("a0", "instance") else "nfal_runtime_handle"
        if name in _POINTER_OUTPUTS:  # hosts that ignore the error status (ecos) must not read garbage pointers
            lines += [f"    if (!{guard}) {{", f"        {_POINTER_OUTPUTS[name]}", f"        return{fail};", "    }"]
        else:
            lines += [f"    if (!{guard}) return{fail};"]
        lines += [f"    return nfal_table.{name}({arguments});", "}", ""]
    return "\n".join(lines)


def _digest(runtime: Runtime) -> str:
    """Hash of the sources, of the Python they are built for and of the CMake that builds them (the cache key)."""
    digest = hashlib.sha256(sysconfig.get_paths()["include"].encode() + cmake.__version__.encode())
    for path in runtime.source_files():
        if path == LOADER_SOURCE:  # the loader has its own key (loader_library)
            continue
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def _cache_dir(runtime: Runtime) -> Path:
    return cache_root() / runtime.cache_name / _digest(runtime)


def exported_functions(library: Path) -> set[str]:
    """The FMI functions ``library`` exports (``nm -D``; a Windows DLL's export table, ``objdump -p``)."""
    if Path(library).suffix == ".dll":
        return {name for name in dll_exports(library) if re.match(r"fmi[23]", name)}
    if shutil.which("nm") is None:
        raise RuntimeBuildError("building the FMU loader needs nm: apt-get install binutils")
    done = subprocess.run(["nm", "-D", "--defined-only", str(library)], capture_output=True, text=True, check=True)
    return {fields[-1] for fields in (line.split() for line in done.stdout.splitlines())
            if len(fields) >= 3 and fields[-2] == "T" and fields[-1].startswith("fmi")}


def _build_loader(runtime: Runtime, library: Path, target: Path, build: Path, *, windows: bool = False) -> None:
    """Compile fmus/loader/loader.c for ``runtime`` (forwarding what ``library`` exports) into ``target``
    (``windows``: a DLL, with mingw-w64)."""
    compiler = mingw_tool("gcc") if windows else shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        raise RuntimeBuildError("building the FMU loader needs a C compiler: apt-get install gcc")
    functions = fmi_functions(runtime.function_types.read_text(encoding="latin-1"))
    exported = exported_functions(library)
    missing = exported - {name for _, name, _ in functions}
    if missing:
        raise RuntimeBuildError(f"the runtime exports FMI functions the headers do not declare: {sorted(missing)}")
    (build / "nfal_forwarders.h").write_text(forwarders_source(functions, exported, runtime.fmi_version),
                                             encoding="utf-8")
    (build / "nfal_python_info.h").write_text(f"#define NFAL_PYTHON_INFO {json.dumps(PYTHON_INFO)}\n"
                                              f"#define NFAL_PYTHON_INFO_HEX \"{PYTHON_INFO.encode().hex()}\"\n",
                                              encoding="utf-8")
    platform = ["-static", "-s", "-lpsapi"] if windows else ["-fPIC", "-fvisibility=hidden", "-ldl", "-lpthread"]
    command = [compiler, "-shared", "-O2", "-Wall", "-Wextra", "-Werror", "-Wno-format-truncation",
               f"-DNFAL_FMI_VERSION={runtime.fmi_version}", f"-I{build}", f"-I{runtime.function_types.parent}",
               f"-I{LOADER_SOURCE.parent}", "-o", str(target), str(LOADER_SOURCE), *platform]
    done = subprocess.run(command, capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
    if done.returncode != 0:
        raise RuntimeBuildError(f"compiling the FMU loader failed:\n{(done.stdout + done.stderr)[-3000:]}")


def runtime_library(fmi_version: int = 2) -> Path:
    """The patched ``libpythonfmu-export.so`` of ``fmi_version`` (2 or 3) for this Python, built with
    CMake on first use (cached by the hash of the sources, :func:`loader_library`'s included).

    Raises
    ------
    RuntimeBuildError
        Not on Linux, or CMake, a C/C++ compiler or the Python headers are missing (the message
        names the Debian packages).
    """
    runtime = RUNTIMES[fmi_version]
    if not sys.platform.startswith("linux"):
        raise RuntimeBuildError(f"the patched FMU runtime is built for Linux only, not {sys.platform}")
    target = _cache_dir(runtime) / LIBRARY_NAME
    build_once(target.is_file, target.parent / BUILD_LOCK, lambda: _build_runtime(runtime, target))
    return target


def _build_runtime(runtime: Runtime, target: Path) -> None:
    if shutil.which("c++") is None:
        raise RuntimeBuildError("building the FMU runtime needs a C++ compiler: "
                                "apt-get install g++ (and python3-dev for the headers)")
    logger.info("compiling the patched FMI %d.0 runtime with CMake: once for this Python, kept in %s",
                runtime.fmi_version, target.parent)
    with tempfile.TemporaryDirectory(prefix="nfal_runtime_", dir=target.parent) as build:
        commands = [[CMAKE, "-S", str(runtime.sources), "-B", build, "-DCMAKE_BUILD_TYPE=Release",
                     f"-DPython3_EXECUTABLE={sys.executable}",
                     # this interpreter's headers: with its venv not activated and pyenv's shims on PATH, CMake's
                     # own search found none and the build failed on a cold cache (tests/test_fmu_loader.py)
                     f"-DPython3_INCLUDE_DIR={sysconfig.get_paths()['include']}"],
                    [CMAKE, "--build", build, "--parallel", "2"]]
        for command in commands:
            done = subprocess.run(command, capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
            if done.returncode != 0:
                raise RuntimeBuildError(f"cmake {command[1]} failed for the FMU runtime in {runtime.sources}:\n"
                                        f"{(done.stdout + done.stderr)[-2000:]}")
        os.replace(Path(build) / runtime.platform / LIBRARY_NAME, target)


def loader_library(fmi_version: int = 2) -> Path:
    """The loader (``fmus/loader/loader.c``) that forwards to :func:`runtime_library`'s runtime: the binary
    a host loads from an FMU (built with the runtime, on first use)."""
    library = runtime_library(fmi_version)
    return _cached_loader(fmi_version, library)


def _cached_loader(fmi_version: int, library: Path) -> Path:
    """The loader in front of ``library`` (a Linux .so or a Windows .dll), built beside it on first use."""
    windows = library.suffix == ".dll"
    source = LOADER_SOURCE.read_bytes() + (LOADER_WINDOWS_HEADER.read_bytes() if windows else b"")
    # the sources, what the loader is generated from, and how it is compiled (_build_loader's flags)
    key = hashlib.sha256(source + PYTHON_INFO.encode() + _GENERATOR_VERSION + Path(__file__).read_bytes()
                         ).hexdigest()[:12]
    target = library.parent / f"{Path(LOADER_NAME).stem}-{key}{library.suffix}"

    def build() -> None:
        with tempfile.TemporaryDirectory(prefix="nfal_loader_", dir=target.parent) as folder:
            built = Path(folder) / f"{Path(LOADER_NAME).stem}{library.suffix}"
            _build_loader(RUNTIMES[fmi_version], library, built, Path(folder), windows=windows)
            os.replace(built, target)

    build_once(target.is_file, target.parent / BUILD_LOCK, build)
    return target


#: The mingw-w64 cross compilers (Debian's g++-mingw-w64-x86-64-posix: the posix threads flavour, whose
#: winpthreads the loader's mutexes use) and binutils.
MINGW_PREFIX = "x86_64-w64-mingw32-"
MINGW_PACKAGE = "g++-mingw-w64-x86-64-posix"
#: How the Windows runtime is compiled (part of its cache key): Python's stable ABI from 3.8 on.
WINDOWS_RUNTIME_FLAGS = ("-std=c++17", "-O2", "-s", "-shared", "-DPy_LIMITED_API=0x03080000",
                         "-Wno-deprecated-declarations")


def dll_exports(library: str | os.PathLike) -> list[str]:
    """The names a Windows DLL exports (its export table, ``objdump -p`` of mingw-w64)."""
    done = subprocess.run([mingw_tool("objdump"), "-p", str(library)], capture_output=True, text=True, check=True)
    table = done.stdout.split("[Ordinal/Name Pointer] Table", 1)[-1]
    return re.findall(r"^\s*\[\s*\d+\]\s+(\w+)\s*$", table, re.M)


def mingw_tool(tool: str) -> str:
    """The path of mingw-w64's ``tool`` (gcc, g++: the posix flavour; objdump), or a RuntimeBuildError naming the
    Debian package."""
    for name in (f"{MINGW_PREFIX}{tool}-posix", f"{MINGW_PREFIX}{tool}"):
        if shutil.which(name):
            return shutil.which(name)
    raise RuntimeBuildError(f"building Windows binaries needs mingw-w64's {tool}: apt-get install {MINGW_PACKAGE}")


def windows_runtime_library(fmi_version: int, python_root: Path) -> Path:
    """The patched runtime of ``fmi_version`` as a win64 DLL, cross-compiled with mingw-w64 against the headers
    and ``python3.dll`` of the Windows CPython in ``python_root`` (fmus/windows_python.py): Python's stable ABI,
    so it runs with any Windows CPython 3.8 or newer. The C++ runtime is linked statically: the DLL needs
    KERNEL32, msvcrt and python3.dll only. Cached by the hash of the sources and the headers' version."""
    runtime = RUNTIMES[fmi_version]
    check_windows_python(python_root)
    include, python3 = Path(python_root) / "include", Path(python_root) / "python3.dll"
    digest = hashlib.sha256((include / "patchlevel.h").read_bytes() + " ".join(WINDOWS_RUNTIME_FLAGS).encode())
    for path in runtime.source_files():
        if path != LOADER_SOURCE:
            digest.update(path.name.encode() + path.read_bytes())
    target = cache_root() / f"{runtime.cache_name}-win64" / digest.hexdigest()[:16] / "pythonfmu-export.dll"
    build_once(target.is_file, target.parent / BUILD_LOCK,
               lambda: _cross_compile_runtime(runtime, include, python3, target))
    return target


def _cross_compile_runtime(runtime: Runtime, include: Path, python3: Path, target: Path) -> None:
    sources = sorted(str(p) for p in (runtime.sources / "src").rglob("*.cpp"))
    partial = target.with_name(f".{target.name}.{os.getpid()}")
    command = [mingw_tool("g++"), *WINDOWS_RUNTIME_FLAGS, f"-I{runtime.sources / 'src'}",
               f"-I{VALUE_CACHE_HEADER.parent}", f"-I{include}", "-o",
               str(partial), *sources, str(python3), "-static", "-static-libgcc", "-static-libstdc++"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
    if done.returncode != 0:
        raise RuntimeBuildError(f"cross-compiling the FMU runtime for Windows failed:\n"
                                f"{(done.stdout + done.stderr)[-3000:]}")
    os.replace(partial, target)


def windows_loader_library(fmi_version: int, python_root: Path) -> Path:
    """The loader as a win64 DLL, in front of :func:`windows_runtime_library` (built on first use)."""
    return _cached_loader(fmi_version, windows_runtime_library(fmi_version, python_root))
