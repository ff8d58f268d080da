"""The real-time discipline (nfal.realtime): bounded latency statistics, the collector in slack, memory locking."""

from __future__ import annotations

import gc
import io
import os
import tracemalloc
import weakref

import numpy as np
import pytest

from nfal.apps.rig_io import RigSample
from nfal.apps.sample_recorder import SampleRecorder
from nfal.realtime import (BINS_PER_DECADE, YOUNG_THRESHOLD, BackgroundWriter, GapStats, LatencyStats,
                           realtime_section)

pytestmark = pytest.mark.realtime  # on the wall clock: one at a time, on one worker (conftest.py)

#: A percentile from the histogram is within half a bin of the exact one (plus the spacing of the sample).
BIN_TOLERANCE = 10 ** (1 / BINS_PER_DECADE) - 1


@pytest.mark.parametrize("seed", [0, 1])
def test_latency_percentiles_match_numpy_within_a_bin(seed):
    values = np.random.default_rng(seed).lognormal(np.log(5e-4), 0.8, 20_000)
    stats = LatencyStats()
    for value in values:
        stats.add(float(value))
    report = stats.report()
    assert report["count"] == values.size and report["max_s"] == values.max()
    assert report["mean_s"] == pytest.approx(values.mean(), rel=1e-12)
    for q in (50, 99):
        assert report[f"p{q}_s"] == pytest.approx(np.percentile(values, q), rel=BIN_TOLERANCE)


def test_latency_stats_hold_zero_and_huge_values_and_report_empty():
    assert LatencyStats().report() == {"count": 0, "mean_s": 0.0, "p50_s": 0.0, "p99_s": 0.0, "max_s": 0.0}
    stats = LatencyStats()
    for value in (0.0, 0.0, 1e6):
        stats.add(value)
    assert stats.percentile(50) < 1e-6 and stats.maximum == 1e6 and stats.percentile(100) == 1e6


def test_gap_stats_count_the_gaps_between_marks():
    gaps = GapStats()
    for t in (1.0, 1.0005, 1.001, 1.021):
        gaps.mark(t)
    assert gaps.count == 3 and gaps.maximum == pytest.approx(0.02)


class Node:
    def __init__(self):
        self.me = self  # a reference cycle: only the cyclic collector frees it


def test_section_turns_the_automatic_collector_off_and_restores_it():
    assert gc.isenabled()
    with realtime_section(lock=False) as collector:
        assert not gc.isenabled() and gc.get_freeze_count() > 0
        garbage = weakref.ref(Node())
        for _ in range(3 * YOUNG_THRESHOLD):  # enough allocations for CPython's own collector to have run
            Node()
        assert garbage() is not None  # nothing collected it behind the loop's back
        collector.safe_point()
        assert garbage() is None  # the safe point did
    assert gc.isenabled() and gc.get_freeze_count() == 0
    assert collector.report()["gc_pauses"]["count"] >= 1


def test_entry_freezes_the_heap_as_it_is_without_walking_it():
    """No full collection on entry: it walks every object the process holds, so a section started in a process that
    holds much started late (the rig emulator's thread in a test worker); what was garbage then waits for the end."""
    gc.collect()  # the young generation empty: nothing collects by itself before the section
    garbage = weakref.ref(Node())
    full_collections = gc.get_stats()[2]["collections"]
    with realtime_section(lock=False):
        assert gc.get_stats()[2]["collections"] == full_collections and garbage() is not None
    gc.collect()
    assert garbage() is None


def test_settle_freezes_what_set_up_built_so_the_first_safe_point_is_cheap():
    with realtime_section(lock=False) as collector:
        built = [Node() for _ in range(3 * YOUNG_THRESHOLD)]  # set-up after the section began
        frozen = gc.get_freeze_count()
        collector.settle()
        assert gc.get_freeze_count() >= frozen + len(built) and gc.get_count()[0] < YOUNG_THRESHOLD
        collector.safe_point()
    assert collector.pauses.count == 0


def test_safe_point_does_nothing_while_the_young_generation_is_small():
    with realtime_section(lock=False) as collector:
        gc.collect(0)
        collector.safe_point()
    assert collector.pauses.count == 0


def test_an_inner_section_is_the_outer_one():
    with realtime_section(lock=False) as outer:
        with realtime_section(lock=False) as inner:
            assert inner is not outer and not inner.memory_locked and "inside another" in inner.memory_lock_note
            garbage = weakref.ref(Node())
            for _ in range(YOUNG_THRESHOLD):
                Node()
            inner.safe_point()
            assert garbage() is None  # the process's collector, whichever section's safe point
        assert not gc.isenabled()  # the inner one's end is not the section's
    assert gc.isenabled()


def test_memory_is_locked_or_the_report_says_why():
    with realtime_section() as collector:
        report = collector.report()
        with realtime_section() as inner:  # an inner section reports what the outer did
            assert inner.memory_locked == report["memory_locked"]
    assert report["memory_locked"] or "memory not locked" in report["memory_lock_note"]


class Refusing(io.StringIO):
    """A file whose disk is full from the ``after``-th write on."""

    def __init__(self, after: int) -> None:
        super().__init__()
        self.after = after

    def write(self, text: str) -> int:
        self.after -= 1
        if self.after < 0:
            raise OSError(28, "No space left on device")
        return super().write(text)

    def close(self) -> None:  # keep the text readable after close()
        pass


def test_background_writer_writes_everything_in_order_on_close():
    file = Refusing(after=10**9)
    writer = BackgroundWriter(file)
    for k in range(1000):
        writer.write(f"{k}\n")
        if k % 100 == 0:
            writer.flush()
    writer.close()
    assert file.getvalue() == "".join(f"{k}\n" for k in range(1000))


def test_a_refused_write_is_raised_by_a_later_call_or_by_close():
    writer = BackgroundWriter(Refusing(after=1))
    writer.write("a\n")
    writer.flush()  # the thread writes "a": fine
    writer.write("b\n")
    writer.flush()  # the thread's second write is refused
    writer._thread.join(timeout=10)
    with pytest.raises(OSError, match="No space"):
        writer.write("c\n")
    with pytest.raises(OSError, match="No space"):
        writer.close()


def test_the_recorder_keeps_no_object_per_sample(tmp_path):
    """The identification's recorder: 20 000 samples cost no memory beyond its preallocated columns."""
    stream = open(os.devnull, "w", encoding="utf-8")  # the disk's side is the BackgroundWriter's tests'
    recorder = SampleRecorder(stream, capacity=30_000)
    batch = [RigSample(k * 5e-4, 1e-4, 28500.0, 50.0, False) for k in range(2)]
    recorder.add(batch, 50.0, "warm")
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    for k in range(10_000):
        recorder.add(batch, 50.0, "hold")
    grown = tracemalloc.get_traced_memory()[0] - before
    tracemalloc.stop()
    stream.close()
    assert recorder.count == 20_002
    assert grown < 50_000  # bytes (a RigSample kept per sample: ~2 MB)
