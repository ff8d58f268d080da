"""FMU files extracted once per process: :func:`extracted`.

A run extracts each FMU it instantiates. Extracted anew for every run, an FMU cost each run the unzip and, for a
Python FMU, a new import of everything it carries (compiling its modules, loading its compiled kernels), kept for the
rest of the process (``python bench/bench_startup.py`` times short runs in one Python both ways). Here an FMU
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
import io
import os
import shutil
import tempfile
import threading
from pathlib import Path

from fmpy import extract

_lock = threading.Lock()
#: {SHA-256 of an FMU file: its extracted folder}, and the folder holding them, made by this process (a forked child
#: makes its own for what it extracts: :func:`_after_fork`).
_folders: dict[str, str] = {}
_root: str | None = None


def extracted(fmu: str | os.PathLike) -> str:
    """The folder of the FMU file ``fmu``, extracted on first use in this process (its content's folder after
    that); fmpy's errors as :func:`fmpy.extract` raises them. The content is read once: what is extracted is what
    was hashed, whatever replaces the file meanwhile."""
    data = Path(fmu).read_bytes()
    key = hashlib.sha256(data).hexdigest()
    with _lock:
        folder = _folders.get(key)
        if folder is None or not os.path.isdir(folder):
            into = tempfile.mkdtemp(dir=_process_root(), prefix=f"{key[:16]}-")
            folder = str(extract(io.BytesIO(data), unzipdir=into))
            _folders[key] = folder
        return folder


def forget(folder: str) -> None:
    """Extract the FMU of ``folder`` (one :func:`extracted` gave) afresh, into a new folder, on its next use (the old
    folder stays: a library loaded from it may still be in use)."""
    with _lock:
        for key in [key for key, held in _folders.items() if held == folder]:
            del _folders[key]


def _process_root() -> str:
    """This process's folder of extracted FMUs, removed at its exit (not after ``os._exit`` or a kill: such a
    process's folder stays in the temporary folder)."""
    global _root
    if _root is None or not os.path.isdir(_root):
        _root = tempfile.mkdtemp(prefix="nfal-fmus-")
        atexit.register(_remove, _root, os.getpid())
    return _root


def _remove(root: str, owner: int) -> None:
    if os.getpid() == owner:  # a forked child runs its parent's exit handlers too
        shutil.rmtree(root, ignore_errors=True)


def _after_fork() -> None:
    """A forked child: uses the FMUs its parent extracted, puts what it extracts in a folder of its own (the parent's
    is the parent's to remove), and gets a lock no thread of the parent may hold."""
    global _lock, _root
    _lock, _root = threading.Lock(), None


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork)
