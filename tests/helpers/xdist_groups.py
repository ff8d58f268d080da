"""``--dist loadgroup`` that groups: pytest-xdist's own stopped grouping with pytest 9.2 (structured node ids; the
suffix it writes into a collected item's id no longer reaches its scheduler, so each test is handed out alone:
pytest-dev/pytest-xdist#1386). Here each worker writes the groups of the items it collected (their ``xdist_group``
marks) to a file the controller named, and the controller's scheduler reads them from there. Drop it (and its line
in conftest.py) once xdist groups again with the pytest in use.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import pytest
from xdist.scheduler import LoadScopeScheduling

#: The environment variable that names the file, set by the controller before it starts the workers.
GROUPS_FILE_ENV = "NFAL_TEST_XDIST_GROUPS"


class XdistGroups:
    """The plugin (conftest.py registers it where xdist is loaded): on the controller it names the file and makes the
    scheduler, on a worker it writes the groups once the suite's marks are on the items."""

    def __init__(self, config) -> None:
        self.folder = None
        if not hasattr(config, "workerinput") and config.getoption("dist") == "loadgroup":
            self.folder = Path(tempfile.mkdtemp(prefix="nfal-xdist-groups-"))
            os.environ[GROUPS_FILE_ENV] = str(self.folder / "groups.json")  # the workers inherit it

    @pytest.hookimpl(tryfirst=True)
    def pytest_xdist_make_scheduler(self, config, log):
        return GroupScheduling(config, log) if self.folder is not None else None

    @pytest.hookimpl(trylast=True)
    def pytest_collection_modifyitems(self, config, items) -> None:
        if hasattr(config, "workerinput") and GROUPS_FILE_ENV in os.environ:
            write_groups(Path(os.environ[GROUPS_FILE_ENV]), items)

    def pytest_unconfigure(self, config) -> None:
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)


def write_groups(path: Path, items) -> None:
    """``{node id: group}`` of the collected ``items`` that have an ``xdist_group`` mark. Every worker collects the
    same items (xdist checks), so whichever writes last writes the same file."""
    groups = {}
    for item in items:
        names = {str(mark.args[0] if mark.args else mark.kwargs.get("name", "default"))
                 for mark in item.iter_markers("xdist_group")}
        if names:
            groups[item.nodeid] = "_".join(sorted(names))
    partial = path.with_name(f"{path.name}.{os.getpid()}")
    partial.write_text(json.dumps(groups), encoding="utf-8")
    partial.replace(path)


class GroupScheduling(LoadScopeScheduling):
    """xdist's load-scope scheduling with a test's scope its group (as ``loadgroup``'s), else the test itself. Work
    units go out largest first (``--loadscope-reorder``, the default): the groups before the single tests."""

    def __init__(self, config, log=None) -> None:
        super().__init__(config, log)
        self._groups: dict[str, str] | None = None

    def _split_scope(self, nodeid: str) -> str:
        if self._groups is None:  # first asked once every worker has collected (and so written the file)
            self._groups = json.loads(Path(os.environ[GROUPS_FILE_ENV]).read_text(encoding="utf-8"))
        return self._groups.get(nodeid, nodeid)
