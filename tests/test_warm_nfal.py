"""The warm command line (tests/helpers/warm_nfal.py) is started as Popen starts one: its session, then preexec_fn."""

from __future__ import annotations

import functools
import os
import resource
from pathlib import Path

import pytest
from helpers import warm_nfal
from helpers.warm_nfal import NFAL, WarmProcess, popen

OPEN_FILES = 200


def _cap_open_files(count: int) -> None:
    resource.setrlimit(resource.RLIMIT_NOFILE, (count, count))


@pytest.mark.slow  # an emulator forked and stopped
def test_a_new_session_and_a_preexec_fn_are_both_kept(fig7_archives, tmp_path):
    process = popen([*NFAL, "rig-emulator", "--truth", str(fig7_archives["rig_slow"]), "--link", str(tmp_path / "rig"),
                     "--duration", "30"], start_new_session=True,
                    preexec_fn=functools.partial(_cap_open_files, OPEN_FILES))
    try:
        assert isinstance(process, WarmProcess) and process.stdout.readline().strip()
        assert os.getsid(process.pid) == process.pid  # a session of its own
        limits = Path(f"/proc/{process.pid}/limits").read_text()
        assert any(line.startswith("Max open files") and line.split()[3:5] == [str(OPEN_FILES)] * 2
                   for line in limits.splitlines()), limits
    finally:
        process.terminate()
        process.communicate(timeout=20)


def _kernels_compiled() -> bool:
    from nfal.models import slow_kernels

    return hasattr(slow_kernels.free_flight, "py_func")  # a numba function, not the Python one (models/jit.py)


@pytest.mark.slow  # a fork server started, its preload compiled
def test_what_is_forked_has_the_plants_kernels_compiled():
    """The fork server's preload (multiprocessing skips a module it cannot import, without a word)."""
    warm_nfal._start_server()
    with warm_nfal._CONTEXT.Pool(1) as pool:
        assert pool.apply(_kernels_compiled)
