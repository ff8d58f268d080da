"""StealWatch: the hypervisor's share of the vCPUs while a loop runs, as the real-time reports and the CLI give it."""

from __future__ import annotations

from pathlib import Path

import pytest

from nfal.cli.commands.common import steal_text
from nfal.orchestration.pacing import STEAL_EVERY, RealTimePacer
from nfal.realtime import StealWatch, steal_s


def watched(burst: tuple[float, float], *, cpus: int = 2, every: float = 0.05, seconds: float = 10.0) -> dict:
    """A watch sampled every ``every`` s over ``seconds`` while one vCPU is fully taken during ``burst``."""
    watch, stolen = StealWatch(), 0.0
    watch._cpus = cpus
    for i in range(round(seconds / every) + 1):
        now = i * every
        if burst[0] < now <= burst[1]:
            stolen += every
        watch.sample(now=now, stolen=stolen)
    return watch.report()


def test_a_burst_shows_as_the_worst_second_and_when_it_ended():
    report = watched((3.0, 3.5))
    assert report["worst_second_percent"] == pytest.approx(25.0)  # half a second of one vCPU in two
    assert report["worst_second_at_s"] == pytest.approx(3.5)
    assert report["share_percent"] == pytest.approx(100 * 0.5 / (10.0 * 2))
    assert report["last_second_percent"] == 0.0


def test_a_burst_at_the_end_shows_in_the_last_second():
    report = watched((9.0, 10.0), cpus=1)
    assert report["last_second_percent"] == pytest.approx(100.0)
    assert report["worst_second_percent"] == pytest.approx(100.0) and report["worst_second_at_s"] == pytest.approx(10.0)


def test_a_watch_keeps_a_bounded_number_of_samples_however_often_it_is_sampled():
    watch = StealWatch()
    for i in range(200_000):
        watch.sample(now=i * 1e-5, stolen=0.0)  # 100 000 samples a second
    assert len(watch._recent) <= 22 and watch.report()["worst_second_percent"] == 0.0


def test_a_watch_shorter_than_a_second_has_no_worst_second_and_nothing_measured_is_none():
    assert watched((0.0, 0.1), seconds=0.5)["worst_second_percent"] is None
    assert StealWatch().report() == {"share_percent": None, "worst_second_percent": None, "worst_second_at_s": None,
                                     "last_second_percent": None}


def test_linux_says_its_steal_and_it_never_runs_backwards():
    if not Path("/proc/stat").exists():
        assert steal_s() is None  # nothing to read: the report's fields are None, not an error
        return
    first = steal_s()
    assert isinstance(first, float) and first >= 0.0 and steal_s() >= first


def test_the_pacer_samples_the_steal_and_reports_it():
    clock = iter(i * 1e-4 for i in range(10 ** 6))
    pacer = RealTimePacer(5e-4, clock=lambda: next(clock), sleep=lambda s: None)
    pacer.start()
    for k in range(3 * STEAL_EVERY):
        pacer.wait(k)
        pacer.done(k)
    steal = pacer.report()["steal"]
    assert set(steal) == {"share_percent", "worst_second_percent", "worst_second_at_s", "last_second_percent"}
    assert steal_s() is None or steal["share_percent"] is not None  # sampled at steps 0, 100 and 200


def test_the_cli_says_the_steal_only_when_there_was_some():
    assert steal_text(None) is None
    assert steal_text(watched((0.0, 0.0))) is None
    line = steal_text(watched((3.0, 3.5)))
    assert "25.0 % in its worst second (ending 3.5 s in)" in line and "0.0 % in its last" in line
