"""Shared fixtures, and the rule that lets the suite run on both cores (pytest-xdist): the tests marked ``realtime``
(they meet the rig emulator on the wall clock) run one after another on one worker, beside the rest on the other."""

import os
import shutil
import sys

# bytecode written, whatever PYTHONDONTWRITEBYTECODE says (images and sandboxes set it): without it each of the suite's
# processes compiles every test and nfal module it imports from source, and a worker's collection takes 11.0 s
# instead of 6.3 s (pytest --collect-only); the workers and every process a test starts inherit this
sys.dont_write_bytecode = False
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
# one BLAS thread per process, before numpy loads, here and in every process a test starts: the suite keeps both
# cores busy, and OpenBLAS's idle threads spin beside the other worker's (tests/test_sampled_design.py and
# test_stability.py on two workers: 25.0 s, 14.8 s with one thread). Dask's nanny does the same for its workers.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# every CMake build the suite makes goes through ccache where it is there (.ci/run installs it): the runtimes the
# fixtures build first fill it, and tests/test_fmu_loader.py's builds from a cold nfal cache take its output, also on
# a machine whose ccache starts empty (0.7 s each after the runtimes were built so, 8.7 and 7.8 s when they were not;
# both builds run the same CMake, fmus/export_runtime.CMAKE)
if shutil.which("ccache"):
    for language in ("C", "CXX"):
        os.environ.setdefault(f"CMAKE_{language}_COMPILER_LAUNCHER", "ccache")

import matplotlib  # noqa: E402

matplotlib.use("Agg")


import pytest  # noqa: E402

from helpers import properties  # noqa: E402
from helpers.xdist_groups import XdistGroups  # noqa: E402

#: The xdist group of the real-time tests: ``--dist loadgroup`` (pyproject.toml) gives a group to one worker.
REALTIME_GROUP = "realtime"


def pytest_configure(config):
    properties.fast_path = "not slow" in (config.option.markexpr or "")  # fewer examples (helpers/properties.py)
    if config.pluginmanager.hasplugin("xdist"):
        config.pluginmanager.register(XdistGroups(config))  # loadgroup's grouping, restored (helpers/xdist_groups.py)


def pytest_collection_modifyitems(items):
    """A ``realtime`` test is also ``slow`` (the fast path, ``-m "not slow"``, meets no wall clock) and in the real-time
    group: one worker runs them in turn, the other the rest meanwhile, so that none waits for another real-time test
    and none leaves a core idle. They pass beside a CPU-bound process (``python bench/realtime.py tests --neighbour``),
    as on a user's busy machine. The groups go out first, largest first, then the other tests in file order."""
    for item in items:
        if item.get_closest_marker("realtime") is not None:
            if item.get_closest_marker("slow") is None:
                item.add_marker(pytest.mark.slow)
            item.add_marker(pytest.mark.xdist_group(REALTIME_GROUP))


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
