"""Shared fixtures, and the rule that lets the suite run on both cores (pytest-xdist) without flaking: a test
marked ``realtime`` (it meets the rig emulator on the wall clock) runs alone, every other test beside another."""

import fcntl
import os
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")


import pytest  # noqa: E402

#: Where the workers of one run meet (pytest-xdist gives them a common run id; a plain run has one process).
_LOCKS = Path(tempfile.gettempdir()) / f"nfal-tests-{os.environ.get('PYTEST_XDIST_TESTRUNUID', os.getpid())}"


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """A readers-writer lock over the workers, held from a test's set-up (its module's fixtures too) to its
    teardown: a ``realtime`` test holds it exclusively, any other test shared. The turnstile, taken before either,
    keeps a waiting real-time test from being overtaken by the next shared ones."""
    _LOCKS.mkdir(exist_ok=True)
    alone = item.get_closest_marker("realtime") is not None
    with open(_LOCKS / "turnstile", "a") as turnstile, open(_LOCKS / "tests", "a") as tests:
        fcntl.flock(turnstile, fcntl.LOCK_EX)
        fcntl.flock(tests, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        fcntl.flock(turnstile, fcntl.LOCK_UN)
        yield


def pytest_collection_modifyitems(items):
    """A ``realtime`` test is also ``slow``: the fast path (``-m "not slow"``) meets no wall clock. The real-time tests
    run last, together: each waits for the other worker's test to end before it starts (the lock above), so spread among
    the rest they left a core idle for the longest test under way every time (about 220 s of a 860 s suite), and at the
    end they wait only for each other. pyproject.toml's ``--dist load`` hands tests out in this order (``worksteal``
    would hand the last ones to the first idle worker while the other still ran the rest)."""
    for item in items:
        if item.get_closest_marker("realtime") is not None and item.get_closest_marker("slow") is None:
            item.add_marker(pytest.mark.slow)
    items.sort(key=lambda item: item.get_closest_marker("realtime") is not None)  # stable: file order kept in each


@pytest.fixture(scope="session")
def fig7_archives(tmp_path_factory):
    """The FMUs built and both Fig. 7 structures packed once per test session: {name: .ssp path}."""
    from nfal.apps.build import build_all

    return build_all(tmp_path_factory.mktemp("fig7_build"))


@pytest.fixture
def emulator(fig7_archives):
    """``emulator(*options)`` starts ``nfal rig-emulator`` on the session's rig_slow.ssp (tests/helpers/rig.py); each
    is stopped after the test."""
    from helpers.rig import Emulator

    started = []

    def start(*options: str) -> Emulator:
        started.append(Emulator(fig7_archives["rig_slow"], *options))
        return started[-1]

    yield start
    for process in started:
        process.stop()
