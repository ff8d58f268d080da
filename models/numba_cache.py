"""numba's on-disk cache of the film kernels, kept across FMU extractions.

numba caches a ``cache=True`` kernel next to its source (``__pycache__``) and checks it against the
source's content hash. An FMU carries its own copy of nfal, which every host run unpacks into a new
temporary folder: each run would compile the kernels again in its set-up (the harmonic-balance plant's
RK4: ~1 s idle, 2 s on a loaded machine; more than the 3.7 s staircase's whole loop). This locator, tried
before numba's own, keeps the cache of this package's kernels in one folder per source *content*
(``$NFAL_CACHE_DIR`` or ``~/.cache/nfal``, ``numba/<module>-<sha256>``): the checkout and every FMU's
copy of the same source share one cache, different sources never meet. Where that folder cannot be
written, numba's own locators take over.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from numba.core import caching

from nfal.cache_folder import cache_root

PACKAGE_DIR = Path(__file__).resolve().parent
#: numba's locator beside the source (public from numba 0.61 on, ``_InTreeCacheLocator`` before).
_IN_TREE_LOCATOR = getattr(caching, "InTreeCacheLocator", None) or caching._InTreeCacheLocator


class ContentKeyedCacheLocator(_IN_TREE_LOCATOR):
    """numba cache locator for the kernels of this package: a folder keyed by the source file's content."""

    def __init__(self, py_func, py_file) -> None:
        super().__init__(py_func, py_file)
        source = Path(py_file)
        # numba checks a cache against its own function's file only: the kernels of other files it calls
        # (the module's KERNEL_DEPENDENCIES, beside it) are part of the key too
        files = [source, *(source.with_name(name) for name in py_func.__globals__.get("KERNEL_DEPENDENCIES", ()))]
        self._digest = hashlib.sha256(b"".join(path.read_bytes() for path in files)).hexdigest()
        self._cache_path = str(cache_root() / "numba" / f"{Path(py_file).stem}-{self._digest[:24]}")

    def get_source_stamp(self) -> str:
        """The sources' content, not the file's mtime and size as numba 0.60 (the Windows Python's,
        fmus/windows_python.py) stamps it (0.68 hashes the content): every host extracts an FMU anew, with new
        mtimes, so such a numba found the cache stale and compiled the kernels again in every run."""
        return self._digest

    @classmethod
    def from_function(cls, py_func, py_file):
        try:
            ours = Path(py_file).resolve().parent == PACKAGE_DIR
        except OSError:
            return None
        return super().from_function(py_func, py_file) if ours else None


def install() -> None:
    """Try :class:`ContentKeyedCacheLocator` first for every kernel defined after this (idempotent; a numba
    without the list of locators keeps its own behaviour). Called by each kernel module before its kernels,
    not by the package: modules without kernels (the Controller's, the proxy's) do not import numba."""
    locators = getattr(getattr(caching, "CacheImpl", None), "_locator_classes", None)
    if isinstance(locators, list) and ContentKeyedCacheLocator not in locators:
        locators.insert(0, ContentKeyedCacheLocator)
