"""The patched FMU runtimes are upstream plus their patch series, nothing else (fmus/runtime*/UPSTREAM.md)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from nfal.fmus.runtime_upstream import RUNTIMES, blob_id, check, series

FMUS = Path(__file__).resolve().parents[1] / "fmus"


def test_blob_id_is_gits():
    assert blob_id(b"hello\n") == "ce013625030ba8dba906f756967f9e9ca394464a"  # git hash-object of "hello\n"


@pytest.mark.parametrize("runtime", RUNTIMES)
def test_the_tree_is_upstream_plus_the_series(runtime):
    folder = FMUS / runtime
    assert series(folder), "no patch series"
    assert check(folder) == []


def test_a_change_outside_the_series_is_found(tmp_path):
    folder = tmp_path / "runtime"
    shutil.copytree(FMUS / "runtime", folder)
    with open(folder / "src" / "pythonfmu" / "SlaveInstance.hpp", "a", encoding="utf-8") as handle:
        handle.write("// an edit no patch records\n")
    (folder / "src" / "extra.cpp").write_text("int x;\n", encoding="utf-8")
    edited, upstream = (blob_id((base / "src/pythonfmu/SlaveInstance.hpp").read_bytes())[:12]
                        for base in (folder, FMUS / "runtime"))
    assert check(folder) == ["src/extra.cpp: not upstream's (add it to upstream.json or remove it)",
                             f"src/pythonfmu/SlaveInstance.hpp: blob {edited}, upstream's {upstream}: a change outside "
                             "the series"]


def test_a_patch_that_no_longer_applies_is_named(tmp_path):
    folder = tmp_path / "runtime"
    shutil.copytree(FMUS / "runtime", folder)
    (folder / "src" / "pythonfmu" / "Logger.hpp").write_text("// rewritten\n", encoding="utf-8")
    with pytest.raises(ValueError, match="0002-src-pythonfmu-Logger.hpp.patch does not come back out"):
        check(folder)
