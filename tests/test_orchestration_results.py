"""Results (CSV streamed with units, summary.json, plot) and real-time pacing, without FMUs."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from helpers.properties import examples
from hypothesis import given
from hypothesis import strategies as st

from nfal.errors import DataFormatError, InvalidParameterError
from nfal.orchestration.pacing import RealTimePacer
from nfal.orchestration.results import (MAX_LINE_SAMPLES, Column, CsvWriter, PlotPanel, default_panels, extremes,
                                        plot_response, read_results, response_figure, write_summary)

COLUMNS = (Column("time", "s"), Column("reference", "m"), Column("Plant.height", "m"),
           Column("Plant.resting", None, "Boolean"), Column("Sensor.count", None, "Integer"))


def test_rows_are_readable_while_the_writer_is_still_open(tmp_path):
    writer = CsvWriter(tmp_path / "r.csv", COLUMNS, flush_interval_s=0.0)
    writer.write([0.0, 6e-5, 6e-5, 1, 0])
    writer.write([0.0005, 1e-4, 6.000000000000001e-5, 0, 3])
    table = read_results(tmp_path / "r.csv")  # as after a crash: never closed
    assert table.names == ("time", "reference", "Plant.height", "Plant.resting", "Sensor.count")
    assert table.units == ("s", "m", "m", None, None)
    assert table["Plant.height"][1] == 6.000000000000001e-5  # full precision
    assert len(table) == 2 and table.unit("reference") == "m"
    writer.close()
    assert (tmp_path / "r.csv").read_text().splitlines()[0] == \
        "time [s],reference [m],Plant.height [m],Plant.resting,Sensor.count"


def test_names_with_commas_quotes_and_newlines_are_read_back(tmp_path):
    """An SSD's element may be named 'Sensor,Chain=1' with a line break: the header quotes it, and the reader, which
    matched the name up to the line break only, failed on it ("'NoneType' object is not subscriptable")."""
    columns = (Column("time", "s"), Column('Sensor,Chain="1"\nx.measured_height', "m"))
    with CsvWriter(tmp_path / "r.csv", columns) as writer:
        writer.write([0.0, 6e-5])
    table = read_results(tmp_path / "r.csv")
    assert table.names == ("time", 'Sensor,Chain="1"\nx.measured_height') and table.units == ("s", "m")


@examples(100)
@given(st.lists(st.lists(st.floats(allow_nan=False, allow_infinity=False, width=64), min_size=3, max_size=3),
                min_size=1, max_size=20))
def test_csv_round_trip_is_exact(rows):
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "r.csv"
        with CsvWriter(path, COLUMNS[:3]) as writer:
            for row in rows:
                writer.write(row)
        np.testing.assert_array_equal(read_results(path).data, np.array(rows))


def test_header_only_and_bad_files(tmp_path):
    CsvWriter(tmp_path / "empty.csv", COLUMNS).close()
    assert read_results(tmp_path / "empty.csv").data.shape == (0, 5)
    (tmp_path / "bad.csv").write_text("time [s],x\n0,1\n1\n")
    with pytest.raises(DataFormatError):
        read_results(tmp_path / "bad.csv")


def test_summary_is_json_with_nan_as_null(tmp_path):
    path = write_summary(tmp_path / "summary.json", {"a": np.float64(1.5), "b": math.nan, "c": [np.int64(2)],
                                                     "d": tmp_path, "e": np.arange(2)})
    assert json.loads(path.read_text()) == {"a": 1.5, "b": None, "c": [2], "d": str(tmp_path), "e": [0, 1]}


def test_plot_of_chosen_and_default_panels(tmp_path):
    with CsvWriter(tmp_path / "r.csv", COLUMNS) as writer:
        for k in range(50):
            writer.write([k * 1e-3, 6e-5 if k < 10 else 1e-4, 6e-5 + k * 1e-6, 0, k])
    table = read_results(tmp_path / "r.csv")
    panels = default_panels(table)
    assert panels[0].columns == ("reference", "Plant.height") and panels[0].scale == pytest.approx(1e6)
    assert panels[0].ylabel == "[um]"
    plot_response(table, tmp_path / "auto.png")
    plot_response(table, tmp_path / "chosen.png", [PlotPanel(("reference", "Plant.height"), 1e6, "height [um]")])
    assert (tmp_path / "chosen.png").stat().st_size > 1000
    with pytest.raises(InvalidParameterError, match="Plant.speed"):
        plot_response(table, tmp_path / "x.png", [PlotPanel("Plant.speed")])


@pytest.mark.parametrize("content, message", [
    (b"time [s],x [m]\n0,1\n1\n", "not a table of numbers"),
    (b"time [s],x [m]\n0,1\n" + b"1,2\n" * 5000 + b"2,\xff\n", "not UTF-8 text"),  # far past the header's block
    (b"time [s],x [\xb5m]\n0,1\n", "not UTF-8 text"),
], ids=["a short row", "a bad byte in a row", "a bad byte in the header"])
def test_a_damaged_results_file_is_one_clear_error(tmp_path, content, message):
    (tmp_path / "r.csv").write_bytes(content)
    with pytest.raises(DataFormatError, match=message):
        read_results(tmp_path / "r.csv")


def test_blank_lines_in_a_results_file_are_skipped(tmp_path):
    (tmp_path / "r.csv").write_text("time [s],x [m]\n0,1\n   \n\n1,2\n")
    assert list(read_results(tmp_path / "r.csv")["x"]) == [1.0, 2.0]


@examples(100)
@given(st.lists(st.floats(-1e3, 1e3), min_size=1, max_size=300), st.integers(1, 40))
def test_a_line_drawn_through_the_extremes_keeps_every_buckets_peak_and_dip(values, bucket):
    values = np.array(values)
    kept = extremes(values, bucket)
    assert np.all(np.diff(kept) > 0) and kept[0] == 0 and kept[-1] == values.size - 1  # in time order, whole span
    assert kept.size <= 2 * -(-values.size // bucket) + 2
    for start in range(0, values.size, bucket):
        mine = values[kept[(kept >= start) & (kept < start + bucket)]]
        assert mine.min() == values[start:start + bucket].min() and mine.max() == values[start:start + bucket].max()


def test_a_nan_breaks_the_reduced_line_as_it_breaks_the_whole_one():
    values = np.arange(100.0)
    values[37] = np.nan
    assert 37 in extremes(values, 10)


def test_a_long_run_is_plotted_through_its_extremes_and_says_so(tmp_path):
    rows = 3 * MAX_LINE_SAMPLES + 7
    with CsvWriter(tmp_path / "r.csv", COLUMNS[:3]) as writer:
        for k in range(rows):
            writer.write([k * 5e-4, 1e-4, 1e-4 + (5e-5 if k == 12345 else 0.0)])  # one spike of one sample
    figure = response_figure(read_results(tmp_path / "r.csv"), [PlotPanel(("reference", "Plant.height"), 1e6)])
    line = figure.axes[0].get_lines()[1]
    assert len(line.get_xdata()) <= 2 * MAX_LINE_SAMPLES + 4 and max(line.get_ydata()) == pytest.approx(150.0)
    assert "lowest and highest of every 4 samples" in figure.texts[0].get_text()


class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now

    def sleep(self, seconds):
        self.now += seconds + 1e-12  # never a hair short of the deadline (the pacer spins until it)


def test_pacer_releases_on_the_grid_and_counts_overruns():
    clock = FakeClock()
    pacer = RealTimePacer(0.01, spin_s=0.0, clock=clock, sleep=clock.sleep)
    pacer.start()
    durations = [0.002, 0.015, 0.001, 0.002]  # the second step overruns by 5 ms
    for k, duration in enumerate(durations):
        pacer.wait(k)
        clock.now += duration
        pacer.done(k)
    report = pacer.report()
    assert report["overruns"] == 1 and report["first_overruns"][0]["step"] == 1
    assert report["overrun_max_s"] == pytest.approx(0.005)
    assert pacer.stats.lateness.count == 4  # late once (step 2, by 5 ms), then back on the grid:
    assert report["jitter_max_s"] == pytest.approx(0.005) and report["jitter_mean_s"] == pytest.approx(0.00125)
    assert report["jitter_p50_s"] < 1e-6
    pacer.sleep_until(len(durations))
    assert clock.now == pytest.approx(100.04)


def test_a_pacer_with_a_least_sleep_sleeps_it_when_late_too():
    """min_sleep_s: on time, the wait until the release; late (the step before overran), the least sleep anyway."""
    clock = FakeClock()
    slept = []
    pacer = RealTimePacer(0.01, spin_s=0.0, clock=clock, sleep=lambda s: (slept.append(s), clock.sleep(s)),
                          min_sleep_s=1e-4)
    pacer.start()
    for k, duration in enumerate([0.002, 0.015, 0.001]):  # the second step ends 5 ms after the third's release
        pacer.wait(k)
        clock.now += duration
        pacer.done(k)
    assert slept == [1e-4, pytest.approx(0.0079), 1e-4]  # step 0's release is now: the least sleep too
    assert pacer.report()["jitter_max_s"] == pytest.approx(0.0051)  # the 5 ms overrun and the least sleep


def _pacer_growth(pacer, clock, steps: int) -> int:
    """Bytes that the pacer's calls (their stacks pass through pacing.py) hold after ``steps`` more steps: not the
    process's, where another thread (pytest-xdist's, a test's leftover) may allocate meanwhile. What the steal
    sampler's reads of /proc/stat leave in io's caches varies from run to run: 0.8-14.4 kB here."""
    import tracemalloc

    from nfal.orchestration import pacing

    def run(first, count):
        for k in range(first, first + count):
            pacer.wait(k)
            clock.now += 0.001 + 1e-4 * (k % 7)
            pacer.done(k)

    run(0, 1000)
    mine = [tracemalloc.Filter(True, pacing.__file__, all_frames=True)]
    tracemalloc.start(4)  # deep enough to see pacing.py above what its calls allocate (the steal sampler's open: 3)
    try:
        before = tracemalloc.take_snapshot().filter_traces(mine)
        run(1000, steps)
        after = tracemalloc.take_snapshot().filter_traces(mine)
    finally:
        tracemalloc.stop()
    return sum(stat.size_diff for stat in after.compare_to(before, "filename"))


def test_pacer_keeps_nothing_per_step():
    """A paced loop of hours keeps bounded statistics: its memory does not grow with the steps."""
    clock = FakeClock()
    pacer = RealTimePacer(0.01, spin_s=0.0, clock=clock, sleep=clock.sleep)
    pacer.start()
    grown = _pacer_growth(pacer, clock, 20_000)
    report = pacer.report()
    assert report["steps"] == 21000 and report["overruns"] == 0
    assert grown < 48_000  # bytes, for 20 000 steps: a tenth of a float a step (11.6 kB once in CI against 10 kB)
    assert report["step_duration_max_s"] == pytest.approx(0.0016)


class KeepingClock(FakeClock):
    """A clock that keeps every reading: what the pacer's calls keep through it is the pacer's to measure."""

    def __init__(self):
        super().__init__()
        self.readings = []

    def __call__(self):
        self.readings.append(self.now + 0.0)
        return self.now


def test_the_pacers_memory_measure_sees_what_a_pacer_keeps_per_step():
    """The measure above can fail: a float kept per reading of the clock in the pacer's calls is seen (24 bytes or
    more a step, 5000 steps)."""
    clock = KeepingClock()
    pacer = RealTimePacer(0.01, spin_s=0.0, clock=clock, sleep=clock.sleep)
    pacer.start()
    assert _pacer_growth(pacer, clock, 5000) > 120_000


def test_pacer_on_the_real_clock_releases_step_k_at_t0_plus_k_periods():
    """What holds on a loaded machine too: no step before its release, the releases on the schedule t0 + k T however
    late the steps before were (lateness does not add up), and each lateness as late as it was, not more. How late a
    busy machine lets a step be is the benches' (bench/realtime.py)."""
    import time

    pacer = RealTimePacer(0.005)
    pacer.start()
    starts = []
    for k in range(20):
        pacer.wait(k)
        starts.append(time.perf_counter())
        pacer.done(k)
    releases = [pacer.release_time(k) for k in range(20)]
    assert releases == [pacer.start_time + k * 0.005 for k in range(20)]
    lateness = [start - release for start, release in zip(starts, releases)]
    report = pacer.report()
    assert min(lateness) >= 0 and report["steps"] == 20
    assert 0 <= report["jitter_p50_s"] <= report["jitter_max_s"] <= max(lateness)


@pytest.mark.parametrize("kwargs", [{"step_size": 0}, {"step_size": 0.1, "speed": -1}, {"step_size": 0.1, "spin_s": 2},
                                    {"step_size": 0.1, "min_sleep_s": 0.1}, {"step_size": 0.1, "min_sleep_s": -1e-4}])
def test_pacer_rejects_bad_arguments(kwargs):
    with pytest.raises(InvalidParameterError):
        RealTimePacer(**kwargs)
