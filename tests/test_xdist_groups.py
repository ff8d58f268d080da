"""The suite's own scheduling (tests/helpers/xdist_groups.py): a group's tests go to one worker, the rest alone."""

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from helpers import xdist_groups

HELPERS = Path(__file__).parent / "helpers"


class _Item:
    def __init__(self, nodeid: str, *groups: str) -> None:
        self.nodeid, self._marks = nodeid, [pytest.mark.xdist_group(g).mark for g in groups]

    def iter_markers(self, name):
        return iter(self._marks if name == "xdist_group" else [])


def test_the_workers_file_gives_each_grouped_test_its_group_and_every_other_test_itself(tmp_path, monkeypatch):
    path = tmp_path / "groups.json"
    xdist_groups.write_groups(path, [_Item("a.py::t1", "realtime"), _Item("a.py::t2"), _Item("b.py::t3", "y", "x")])
    assert json.loads(path.read_text()) == {"a.py::t1": "realtime", "b.py::t3": "x_y"}  # two marks: one joined group
    monkeypatch.setenv(xdist_groups.GROUPS_FILE_ENV, str(path))
    scheduling = xdist_groups.GroupScheduling.__new__(xdist_groups.GroupScheduling)
    scheduling._groups = None
    assert [scheduling._split_scope(n) for n in ("a.py::t1", "a.py::t2", "b.py::t3")] == ["realtime", "a.py::t2",
                                                                                           "x_y"]


@pytest.mark.slow  # a pytest session with two workers
def test_a_groups_tests_run_on_one_worker_and_the_others_on_both(tmp_path):
    """As the suite runs: ``-n 2 --dist loadgroup`` with conftest.py's plugin; xdist 3.8 alone, with pytest 9.2, hands
    every test out alone (pytest-dev/pytest-xdist#1386)."""
    (tmp_path / "conftest.py").write_text(textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(HELPERS.parent)!r})
        from helpers.xdist_groups import XdistGroups

        def pytest_configure(config):
            config.pluginmanager.register(XdistGroups(config))
        """))
    (tmp_path / "test_many.py").write_text(textwrap.dedent("""
        import time
        import pytest

        @pytest.mark.xdist_group("together")
        @pytest.mark.parametrize("i", range(8))
        def test_grouped(i):
            time.sleep(0.05)

        @pytest.mark.parametrize("i", range(8))
        def test_alone(i):
            time.sleep(0.05)
        """))
    done = subprocess.run([sys.executable, "-m", "pytest", "-n", "2", "--dist", "loadgroup", "-v", "-p",
                           "no:cacheprovider", "-o", "addopts=", str(tmp_path)], cwd=tmp_path, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    workers = {}
    for line in done.stdout.splitlines():
        if line.startswith("[gw") and "PASSED" in line:
            workers.setdefault(line.split("::")[1].split("[")[0], set()).add(line.split("]")[0][1:])
    assert len(workers["test_grouped"]) == 1, done.stdout
    assert set().union(*workers.values()) == {"gw0", "gw1"}, done.stdout
