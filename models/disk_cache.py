"""Arrays kept across processes in the user-wide cache folder (:func:`nfal.cache_folder.cache_root`).

What is kept is a pure function's result, named by a digest of everything it depends on (its inputs and,
where the code may change, the source that computes it): a changed input or source finds no entry and
computes again. A cache that cannot be read or written is bypassed; nothing here can make a result wrong,
only slower.
"""

from __future__ import annotations

import hashlib
import logging
import os
from pathlib import Path
from typing import Callable

import numpy as np

from nfal.cache_folder import cache_root, write_in_one_step

logger = logging.getLogger(__name__)


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
