"""FMU files extracted once per process: :func:`extracted`.

A run extracts each FMU it instantiates. Extracted anew for every run, an FMU cost each run the unzip and, for a
Python FMU, a new import of everything it carries (compiling its modules, loading its compiled kernels), kept for the
rest of the process: 20 runs of ``run_structure("fig7_slow.ssp", stop_time=0.01, plot=False)`` in one Python took
13.5-19.4 s and 284 MiB and left 100 copies of the FMUs' nfal; now 3.7 s, 201 MiB and 5 (2026-11-28). Here an FMU
is extracted once per *content* (the SHA-256 of the file, so a copy unpacked from another archive, or from the same
one again, is found too) into a folder this process removes at exit, and its later runs instantiate it from there,
as a second instance of a run's FMU always did.

:func:`forget` drops an FMU after ``fmi2Fatal`` (FMI then allows no further call to any of its instances, so the
next run extracts it afresh, into a new folder). An FMU that can be instantiated only once per process is not
cached (the master extracts it for each run, as before).
"""

from __future__ import annotations

import atexit
import hashlib
import os
import shutil
import tempfile
import threading

from fmpy import extract

_lock = threading.Lock()
#: {SHA-256 of an FMU file: its extracted folder}, and the folder holding them, made by process ``_owner``.
_folders: dict[str, str] = {}
_root: str | None = None
_owner: int | None = None


def content_key(fmu: str | os.PathLike) -> str:
    """The SHA-256 of the FMU file ``fmu``."""
    digest = hashlib.sha256()
    with open(fmu, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def extracted(fmu: str | os.PathLike) -> str:
    """The folder of the FMU file ``fmu``, extracted on first use in this process (its content's folder after
    that); fmpy's errors as :func:`fmpy.extract` raises them."""
    key = content_key(fmu)
    with _lock:
        folder = _folders.get(key)
        if folder is None or not os.path.isdir(folder):
            folder = str(extract(str(fmu), unzipdir=tempfile.mkdtemp(dir=_cache_root(), prefix=f"{key[:16]}-")))
            _folders[key] = folder
        return folder


def forget(fmu: str | os.PathLike) -> None:
    """Extract ``fmu`` afresh, into a new folder, on its next use (the old folder stays: a library mapped from it is
    never unmapped)."""
    key = content_key(fmu)
    with _lock:
        _folders.pop(key, None)


def _cache_root() -> str:
    """This process's folder of extracted FMUs. A forked child uses the FMUs its parent extracted and puts those it
    extracts itself in a folder of its own: the parent's is the parent's to remove."""
    global _root, _owner
    if _root is None or _owner != os.getpid():
        _root, _owner = tempfile.mkdtemp(prefix="nfal-fmus-"), os.getpid()
        atexit.register(_remove, _root, _owner)
    return _root


def _remove(root: str, owner: int) -> None:
    if os.getpid() == owner:
        shutil.rmtree(root, ignore_errors=True)
