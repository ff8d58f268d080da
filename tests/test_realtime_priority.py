"""SCHED_FIFO for paced loops: realtime_priority, run_structure(rt_priority=), and the CLI's --rt-priority."""

import json
import os
import threading

import pytest

from nfal.cli import main
from nfal.errors import InvalidParameterError, RealtimePriorityError
from nfal.orchestration import run_structure
from nfal.orchestration.pacing import realtime_priority, realtime_priority_refusal

pytestmark = pytest.mark.realtime  # on the wall clock: one at a time, on one worker (conftest.py)

linux_only = pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="SCHED_FIFO is Linux's")


@pytest.fixture
def refused(monkeypatch):
    """The system refuses SCHED_FIFO, as it does to an ordinary user without an rtprio limit."""
    def refuse(pid, policy, param):
        if policy == os.SCHED_FIFO:
            raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)


@pytest.mark.parametrize("priority", [0, 100, -1, 1.5, True, "50"])
def test_a_priority_outside_1_to_99_is_refused(priority):
    with pytest.raises(InvalidParameterError, match="1 to 99"), realtime_priority(priority):
        pytest.fail("the body ran")


@linux_only
def test_none_leaves_the_scheduling_alone():
    before = os.sched_getscheduler(0), os.sched_getparam(0).sched_priority
    with realtime_priority(None):
        assert (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority) == before


@linux_only
def test_the_thread_runs_fifo_inside_and_gets_its_policy_back_after():
    if realtime_priority_refusal(1):
        pytest.skip("this process may not use SCHED_FIFO")
    before = os.sched_getscheduler(0), os.sched_getparam(0).sched_priority
    seen = {}
    with realtime_priority(7):
        seen["inside"] = os.sched_getscheduler(0), os.sched_getparam(0).sched_priority
        worker = threading.Thread(target=lambda: seen.update(thread=os.sched_getscheduler(0)))
        worker.start()
        worker.join()
    assert seen == {"inside": (os.SCHED_FIFO, 7), "thread": os.SCHED_FIFO}  # threads started inside inherit it
    assert (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority) == before
    with pytest.raises(RuntimeError), realtime_priority(7):
        raise RuntimeError("restored on errors too")
    assert os.sched_getscheduler(0) == before[0]


@linux_only
def test_realtime_priority_refusal_says_why(refused):
    assert "CAP_SYS_NICE" in realtime_priority_refusal(50)


@linux_only
def test_a_refusal_says_how_to_get_the_priority(refused):
    with pytest.raises(RealtimePriorityError, match="CAP_SYS_NICE") as caught, realtime_priority(50):
        pytest.fail("the body ran")
    assert isinstance(caught.value, PermissionError)


def test_run_structure_wants_realtime_with_a_priority_and_writes_nothing_without(tmp_path, fig7_archives):
    with pytest.raises(InvalidParameterError, match="realtime"):
        run_structure(fig7_archives["fig7_slow"], stop_time=0.01, rt_priority=50, out_dir=tmp_path / "run")
    assert not (tmp_path / "run").exists()


@linux_only
def test_a_refused_priority_stops_nfal_run_before_anything_runs(capsys, tmp_path, fig7_archives, refused):
    assert main(["run", str(fig7_archives["fig7_slow"]), "--stop-time", "0.01", "--realtime", "--rt-priority", "50",
                 "--out", str(tmp_path / "run")]) == 2
    assert "SCHED_FIFO" in capsys.readouterr().err and not (tmp_path / "run").exists()


@linux_only
def test_a_refused_priority_stops_the_emulator_before_it_opens_a_port(capsys, refused):
    assert main(["rig-emulator", "--rt-priority", "50", "--duration", "0.01"]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and "CAP_SYS_NICE" in captured.err


@linux_only
def test_nfal_run_under_fifo_records_the_priority(capsys, tmp_path, fig7_archives):
    if realtime_priority_refusal(1):
        pytest.skip("this process may not use SCHED_FIFO")
    policy = os.sched_getscheduler(0)
    assert main(["run", "--no-plot", str(fig7_archives["fig7_slow"]), "--stop-time", "0.05", "--realtime",
                 "--rt-priority", "20", "--out", str(tmp_path / "run"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["status"] == "ok" and summary["rt_priority"] == 20 and summary["realtime"]["steps"] == 100
    assert os.sched_getscheduler(0) == policy


def test_nfal_run_wants_realtime_with_a_priority(capsys, tmp_path, fig7_archives):
    assert main(["run", str(fig7_archives["fig7_slow"]), "--stop-time", "0.01", "--rt-priority", "50",
                 "--out", str(tmp_path / "run")]) == 2
    assert "--realtime" in capsys.readouterr().err and not (tmp_path / "run").exists()
