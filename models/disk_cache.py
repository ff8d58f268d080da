"""Arrays kept across processes in the user-wide cache folder (:func:`cache_root`).

What is kept is a pure function's result, named by a digest of everything it depends on (its inputs and,
where the code may change, the source that computes it): a changed input or source finds no entry and
computes again. A cache that cannot be read or written is bypassed; nothing here can make a result wrong,
only slower.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Callable

try:
    import fcntl
except ImportError:  # Windows: an FMU's host there reads the cache, it builds nothing
    fcntl = None

import numpy as np

logger = logging.getLogger(__name__)


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


def digest(*parts: object) -> str:
    """A name for an entry: the SHA-256 of ``parts`` (bytes and arrays as their bytes, anything else as its repr)."""
    hasher = hashlib.sha256()
    for part in parts:
        if isinstance(part, np.ndarray):
            hasher.update(np.ascontiguousarray(part, dtype=float).tobytes())
        elif isinstance(part, bytes):
            hasher.update(part)
        else:
            hasher.update(repr(part).encode())
        hasher.update(b"\0")
    return hasher.hexdigest()[:32]


def source_digest(*modules: str) -> bytes:
    """The content of the source files of ``modules`` (module ``__file__`` paths), for a digest's parts."""
    return b"".join(Path(module).read_bytes() for module in modules)


def cached_array(folder: str, key: str, compute: Callable[[], np.ndarray], root: str | os.PathLike | None = None,
                 check: Callable[[np.ndarray], object] | None = None) -> np.ndarray:
    """The array ``compute()`` returns, kept as ``<root>/<folder>/<key>.npy``. ``check`` (optional) validates
    an array read back and raises if it does not fit (an entry then counts as missing)."""
    path = Path(root or cache_root()) / folder / f"{key}.npy"
    try:
        values = np.load(path)
        if check is not None:
            check(values)
        return values
    except (OSError, ValueError, EOFError):
        pass
    except Exception as exc:  # noqa: BLE001 -- an entry that does not fit is recomputed, whatever the check raised
        logger.debug("cache entry %s not used: %s", path, exc)
    values = compute()
    try:
        write_in_one_step(path, lambda partial: _save(partial, values))
    except OSError as exc:
        logger.debug("not cached in %s: %s", path.parent, exc)
    return values


def _save(path: Path, values: np.ndarray) -> None:
    with open(path, "wb") as handle:  # a handle: np.save would add ".npy" to the partial's name
        np.save(handle, values)
