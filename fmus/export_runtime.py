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
imports its own slave module. FMI 2.0 only: the slave module's borrowed ``__dict__`` is no longer
released (``findClass``), ``%`` is escaped (the FMI 2.0 logger takes a printf format; FMI 3.0's does
not), a second ``fmi2FreeInstance`` of an instance does nothing (``fmi2.cpp`` keeps the set of live
instances), and the ``PyState`` pointer is never destroyed by ``exit()``, so the library's destructor does
not release it a second time (a host aborted at exit, "corrupted double-linked list"). FMI 3.0 only: the log queue is read after the exception is taken (it was read with the exception
pending: SIGSEGV), an import failure is no longer printed away before it is reported, a NULL logger
callback is allowed, two leaks are closed, and a failed reset leaves no dangling references.

:func:`runtime_library` builds one with CMake for the running Python (once; the result is cached by
the hash of the sources) and :mod:`nfal.fmus.build` puts it into every FMU in place of the stock one.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from dataclasses import dataclass
from pathlib import Path

from nfal.errors import RuntimeBuildError


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

    def source_files(self) -> list[Path]:
        return sorted(p for p in self.sources.rglob("*") if p.is_file())


_HERE = Path(__file__).resolve().parent
#: FMI version -> its runtime.
RUNTIMES: dict[int, Runtime] = {
    2: Runtime(_HERE / "runtime", "linux64", "pythonfmu-export"),
    3: Runtime(_HERE / "runtime3", "x86_64-linux", "pythonfmu3-export"),
}
#: The library CMake builds (the builders name the FMU's copy ``binaries/<platform>/<model>.so``).
LIBRARY_NAME = "libpythonfmu-export.so"
BUILD_TIMEOUT_S = 600


def _digest(runtime: Runtime) -> str:
    """Hash of the sources and of the Python they are built for (the cache key)."""
    digest = hashlib.sha256(sysconfig.get_paths()["include"].encode())
    for path in runtime.source_files():
        digest.update(str(path.relative_to(runtime.sources)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def _cache_dir(runtime: Runtime) -> Path:
    root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return root / "nfal" / runtime.cache_name / _digest(runtime)


def runtime_library(fmi_version: int = 2) -> Path:
    """The patched ``libpythonfmu-export.so`` of ``fmi_version`` (2 or 3) for this Python, built with
    CMake on first use.

    Raises
    ------
    RuntimeBuildError
        Not on Linux, or CMake, a C++17 compiler or the Python headers are missing (the message
        names the Debian packages).
    """
    runtime = RUNTIMES[fmi_version]
    if not sys.platform.startswith("linux"):
        raise RuntimeBuildError(f"the patched FMU runtime is built for Linux only, not {sys.platform}")
    target = _cache_dir(runtime) / LIBRARY_NAME
    if target.is_file():
        return target
    if shutil.which("cmake") is None or shutil.which("c++") is None:
        raise RuntimeBuildError("building the FMU runtime needs CMake and a C++ compiler: "
                                "apt-get install cmake g++ (and python3-dev for the headers)")
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="nfal_runtime_", dir=target.parent) as build:
        commands = [["cmake", "-S", str(runtime.sources), "-B", build, "-DCMAKE_BUILD_TYPE=Release",
                     f"-DPython3_EXECUTABLE={sys.executable}"],
                    ["cmake", "--build", build, "--parallel", "2"]]
        for command in commands:
            done = subprocess.run(command, capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
            if done.returncode != 0:
                raise RuntimeBuildError(f"{' '.join(command[:2])} failed for the FMU runtime in {runtime.sources}:\n"
                                        f"{(done.stdout + done.stderr)[-2000:]}")
        os.replace(Path(build) / runtime.platform / LIBRARY_NAME, target)
    return target
