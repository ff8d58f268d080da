"""What a test session builds once for both of its xdist workers: the tests only read it."""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from nfal.cache_folder import build_once


def shared_build(tmp_path_factory: pytest.TempPathFactory, name: str, build: Callable[[Path], object]) -> Path:
    """The folder ``name`` that ``build(folder)`` fills, built by the first worker of the session that asks and found
    built by the other (the workers' temporary folders share the session's parent)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent
    folder, done = root / f"shared-{name}", root / f"shared-{name}.done"

    def fill() -> None:
        shutil.rmtree(folder, ignore_errors=True)  # what a failed build left
        folder.mkdir()
        build(folder)
        done.touch()

    build_once(done.is_file, root / f"shared-{name}.lock", fill)
    return folder
