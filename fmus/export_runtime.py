"""The FMI binary every nfal FMU ships: pythonfmu's C++ export runtime, patched, built from ``fmus/runtime/``.

pythonfmu 0.7.0's prebuilt ``libpythonfmu-export.so`` crashes non-Python hosts at exit and answers
every Python exception with fmi2Fatal (docs/cosimulation.md, "Crash at exit"). ``fmus/runtime/`` is
its source (NTNU-IHB/PythonFMU 6e6f489, MIT) with the fixes marked ``// nfal:``:

* the interpreter is never finalised (``PyState.hpp``), and the slave module's borrowed ``__dict__``
  is no longer released (``findClass``);
* a Python exception is answered with fmi2Error and its ``str()`` as the logged message, and leaves
  the instance whole (``handle_py_exception``); errors reach the host's logger even when
  ``loggingOn`` is false (``Logger.hpp``);
* a second ``fmi2FreeInstance`` of an instance does nothing (``fmi2.cpp`` keeps the set of live instances);
* the ``PyState`` pointer is never destroyed by ``exit()``, so the library's destructor does not release
  it a second time (a host aborted at exit, "corrupted double-linked list").

:func:`runtime_library` builds it with CMake for the running Python (once; the result is cached by
the hash of the sources) and :mod:`nfal.fmus.build` puts it into every FMU in place of pythonfmu's.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

from nfal.models.errors import NfalError

#: The vendored, patched sources.
RUNTIME_SOURCES = Path(__file__).resolve().parent / "runtime"
#: The library CMake builds (pythonfmu's builder names the FMU's copy ``binaries/<platform>/<model>.so``).
LIBRARY_NAME = "libpythonfmu-export.so"
#: The platform folder it goes to inside an FMU.
PLATFORM = "linux64"
BUILD_TIMEOUT_S = 600


class RuntimeBuildError(NfalError, RuntimeError):
    """The patched FMU runtime cannot be built here (no CMake, no C++ compiler, no Python headers)."""


def _source_files() -> list[Path]:
    return sorted(p for p in RUNTIME_SOURCES.rglob("*") if p.is_file())


def _digest() -> str:
    """Hash of the sources and of the Python they are built for (the cache key)."""
    digest = hashlib.sha256(sysconfig.get_paths()["include"].encode())
    for path in _source_files():
        digest.update(str(path.relative_to(RUNTIME_SOURCES)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def _cache_dir() -> Path:
    root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return root / "nfal" / "pythonfmu-export" / _digest()


def runtime_library() -> Path:
    """The patched ``libpythonfmu-export.so`` for this Python, built with CMake on first use.

    Raises
    ------
    RuntimeBuildError
        Not on Linux, or CMake, a C++17 compiler or the Python headers are missing (the message
        names the Debian packages).
    """
    if not sys.platform.startswith("linux"):
        raise RuntimeBuildError(f"the patched FMU runtime is built for Linux only, not {sys.platform}")
    target = _cache_dir() / LIBRARY_NAME
    if target.is_file():
        return target
    if shutil.which("cmake") is None or shutil.which("c++") is None:
        raise RuntimeBuildError("building the FMU runtime needs CMake and a C++ compiler: "
                                "apt-get install cmake g++ (and python3-dev for the headers)")
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="nfal_runtime_", dir=target.parent) as build:
        commands = [["cmake", "-S", str(RUNTIME_SOURCES), "-B", build, "-DCMAKE_BUILD_TYPE=Release",
                     f"-DPython3_EXECUTABLE={sys.executable}"],
                    ["cmake", "--build", build, "--parallel", "2"]]
        for command in commands:
            done = subprocess.run(command, capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
            if done.returncode != 0:
                raise RuntimeBuildError(f"{' '.join(command[:2])} failed for the FMU runtime in {RUNTIME_SOURCES}:\n"
                                        f"{(done.stdout + done.stderr)[-2000:]}")
        os.replace(Path(build) / PLATFORM / LIBRARY_NAME, target)
    return target
