"""The user-wide cache folder (:func:`cache_root`) and how processes share it: one builds what it holds while the
others wait (:func:`exclusive`, :func:`build_once`), and a file appears whole or not at all
(:func:`write_in_one_step`). Every layer keeps what it builds once there: the film tables and designs
(:mod:`nfal.models.disk_cache`), numba's cache, the FMU runtimes, the master's compiled exchange.
"""

from __future__ import annotations

import contextlib
import os
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Callable

try:
    import fcntl
except ImportError:  # Windows: an FMU's host there reads the cache, it builds nothing
    fcntl = None


def cache_root() -> Path:
    """The user-wide cache folder: ``$NFAL_CACHE_DIR``, else ``$XDG_CACHE_HOME/nfal``, else ``~/.cache/nfal`` (also
    numba's, :mod:`nfal.models.numba_cache`, and the FMU runtimes', :mod:`nfal.fmus.export_runtime`)."""
    if os.environ.get("NFAL_CACHE_DIR"):
        return Path(os.environ["NFAL_CACHE_DIR"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "nfal"


@contextlib.contextmanager
def exclusive(lock: str | os.PathLike) -> Iterator[None]:
    """Hold the lock file ``lock`` (created, with its folder): one process at a time builds what it guards, and
    the others, waiting, then find it built (check again inside). Two test workers or sweep workers on a fresh
    machine otherwise built the same runtime at once, or failed to put a second copy of a folder in place."""
    Path(lock).parent.mkdir(parents=True, exist_ok=True)
    with open(lock, "a") as handle:
        if fcntl is not None:
            fcntl.flock(handle, fcntl.LOCK_EX)
        yield


def build_once(done: Callable[[], bool], lock: str | os.PathLike, build: Callable[[], None]) -> None:
    """``build()`` unless ``done()``: under :func:`exclusive` ``lock``, asked again there, so that of several
    processes asking at once one builds and the others find it built."""
    if done():
        return
    with exclusive(lock):
        if not done():
            build()


def write_in_one_step(target: str | os.PathLike, write: Callable[[Path], object]) -> Path:
    """``write(path)`` to a new temporary file beside ``target`` (its folder made), then that file in ``target``'s
    place in one step: a reader never sees half of it, and a ``write`` that raises leaves nothing behind. The file is
    new: its modification time is now."""
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    partial = target.with_name(f".{target.name}.{uuid.uuid4().hex}")  # made by ``write``, with the usual mode
    try:
        write(partial)
        os.replace(partial, target)
    finally:
        if os.path.exists(partial):
            os.remove(partial)
    return target
