"""The film kernels' numba cache is keyed by source content, so an FMU's unpacked copy of nfal reuses it."""

import os
import shutil
from pathlib import Path

from nfal.models import slow_kernels
from nfal.models.numba_cache import ContentKeyedCacheLocator

slow_kernels.load()  # compiled (models/jit.py): numba_cache is imported with numba, which a short run never imports

from nfal.models import numba_cache  # noqa: E402 - after the load above, as nfal imports it


def test_the_kernels_use_the_content_keyed_locator():
    assert isinstance(slow_kernels.curve_value._cache._impl.locator, ContentKeyedCacheLocator)


def test_the_cache_folder_follows_the_content_not_the_place(tmp_path, monkeypatch):
    monkeypatch.setenv("NFAL_CACHE_DIR", str(tmp_path / "cache"))
    kernel, source = slow_kernels.curve_value.py_func, Path(slow_kernels.__file__)
    copy = tmp_path / "unpacked" / "nfal" / "models" / source.name  # where a host unpacks an FMU's copy
    copy.parent.mkdir(parents=True)
    shutil.copy(source, copy)
    edited = tmp_path / "edited" / source.name
    edited.parent.mkdir()
    edited.write_text(source.read_text() + "\n# edited\n")
    here, there, other = (ContentKeyedCacheLocator(kernel, str(path)).get_cache_path()
                          for path in (source, copy, edited))
    assert here == there != other
    assert Path(here).parent == tmp_path / "cache" / "numba"


def test_only_this_package_s_sources_are_located(tmp_path):
    kernel = slow_kernels.curve_value.py_func
    elsewhere = tmp_path / "slow_kernels.py"
    shutil.copy(slow_kernels.__file__, elsewhere)
    assert ContentKeyedCacheLocator.from_function(kernel, str(elsewhere)) is None  # numba's own locators take it
    assert ContentKeyedCacheLocator.from_function(kernel, slow_kernels.__file__) is not None
    numba_cache.install()  # idempotent
    assert numba_cache.caching.CacheImpl._locator_classes.count(ContentKeyedCacheLocator) == 1


def test_a_kernel_s_cache_follows_the_kernels_it_calls_in_other_files(tmp_path, monkeypatch):
    """coupled.py's kernels call film_kernel.py's fluxes and Thomas solver: numba checks only the caller's file, so the
    key does."""
    from nfal.models import coupled

    monkeypatch.setenv("NFAL_CACHE_DIR", str(tmp_path / "cache"))
    kernel, folder = coupled._march_coupled.py_func, tmp_path / "nfal" / "models"
    folder.mkdir(parents=True)
    for name in ("coupled.py", "film_kernel.py"):
        shutil.copy(Path(coupled.__file__).with_name(name), folder / name)
    before = ContentKeyedCacheLocator(kernel, str(folder / "coupled.py")).get_cache_path()
    (folder / "film_kernel.py").write_text((folder / "film_kernel.py").read_text() + "\n# the solver edited\n")
    assert ContentKeyedCacheLocator(kernel, str(folder / "coupled.py")).get_cache_path() != before


def test_the_stamp_is_the_content_not_the_files_time(tmp_path, monkeypatch):
    """A host unpacks an FMU anew each run, with new mtimes: a numba that stamps a cache by mtime and size (0.60, the
    Windows Python's) would compile the kernels again every time, unless the locator stamps the content."""
    monkeypatch.setenv("NFAL_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(numba_cache._IN_TREE_LOCATOR, "get_source_stamp",  # numba 0.60's
                        lambda self: (os.stat(self._py_file).st_mtime, os.stat(self._py_file).st_size))
    kernel, source = slow_kernels.curve_value.py_func, Path(slow_kernels.__file__)
    copy = tmp_path / "unpacked" / "nfal" / "models" / source.name
    copy.parent.mkdir(parents=True)
    shutil.copy(source, copy)
    os.utime(copy, (1e9, 1e9))
    stamps = [ContentKeyedCacheLocator(kernel, str(path)).get_source_stamp() for path in (source, copy)]
    assert stamps[0] == stamps[1]
    copy.write_text(source.read_text() + "\n# edited\n")
    assert ContentKeyedCacheLocator(kernel, str(copy)).get_source_stamp() != stamps[0]
