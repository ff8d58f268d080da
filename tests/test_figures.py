"""The figures the commands write, as a reader sees them: checked on the matplotlib Figure (panels, artists,
ticks), not on pixels."""

import dataclasses

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg

from nfal.apps.fig7 import EXCITATION_COMMAND, SIMULATED, response_panels
from nfal.apps.figures.control import comparison_figure, stability_map_figure
from nfal.apps.figures.physics import calibration_figure
from nfal.models.calibration import paper_calibration
from nfal.models.closed_loop import ClosedLoopRun
from nfal.models.measurement_noise import coloured_noise
from nfal.models.stability import StabilityMap
from nfal.orchestration.results import ResultTable, response_figure
from nfal.orchestration.sweep_plot import sweep_figure
from nfal.apps.sweeps import TABLE1_METRICS, parse_spec


def _stability_map(low: float, high: float) -> StabilityMap:
    heights = np.linspace(50e-6, 200e-6, 7)
    moduli = np.geomspace(low, high, heights.size ** 2).reshape(heights.size, heights.size)
    return StabilityMap(heights, heights, moduli, "forward_euler", 2000.0)


@pytest.mark.parametrize("low, high", [(0.951, 14.8), (0.956, 0.9967), (1.2, 3.0)],
                         ids=["both sides of 1 (the paper's Fig. 8)", "all stable (sampled)", "all unstable"])
def test_stability_map_colour_bar_ticks_both_sides_of_one(low, high):
    figure = stability_map_figure(_stability_map(low, high))
    bar = figure.axes[1]
    ticks = np.asarray(bar.get_yticks())
    bottom, top = bar.get_ylim()
    shown = ticks[(ticks >= bottom) & (ticks <= top)]
    assert shown.size == ticks.size and bottom <= low and high <= top
    if low < 1.0:
        assert np.count_nonzero(shown < 1.0) >= 3, shown  # the stable range that matters has its own ticks
    if high > 1.0:
        assert np.count_nonzero(shown > 1.0) >= 2, shown
    if low < 1.0 < high:
        assert 1.0 in shown


def _closed_loop_run(name: str, noise_peak_m: float = 2e-6) -> ClosedLoopRun:
    """A staircase 60-180-60 um at 2 kHz, the clearance following it, the measurement with coloured noise."""
    time = np.arange(0, 1.2, 5e-4)
    reference = np.select([time < 0.3, time < 0.6, time < 0.9], [60e-6, 120e-6, 180e-6], 60e-6)
    height = np.convolve(reference, np.full(40, 1 / 40), mode="full")[:time.size]
    height[:40] = reference[:40]
    noise = coloured_noise(time.size, sample_rate_hz=2000.0, cutoff_hz=300.0, peak_m=noise_peak_m, seed=1)
    return ClosedLoopRun(name, time, reference, height, height + noise, np.zeros_like(time))


def _line(axis, label: str):
    return next(line for line in axis.get_lines() if line.get_label() == label)


def test_comparison_shows_the_measured_noise_above_the_clearance_line_width():
    runs = {"gs": _closed_loop_run("gain-scheduled"), "80": _closed_loop_run("linear at 80 um")}
    figure = comparison_figure(runs)
    FigureCanvasAgg(figure).draw()
    assert len(figure.axes) == 2 * len(runs)
    # one legend entry per colour: the gain-scheduled line is blue, the linear ones orange
    assert [text.get_text() for text in figure.legends[0].get_texts()] == [
        "measured (with noise)", "clearance: gain-scheduled", "reference", "clearance: linear"]
    for zoom, kind in zip(figure.axes[1::2], ("gain-scheduled", "linear")):
        measured, clearance = _line(zoom, "measured (with noise)"), _line(zoom, f"clearance: {kind}")
        assert measured.get_visible() and (measured.get_alpha() is None or measured.get_alpha() >= 0.8)
        assert measured.get_linewidth() >= 0.5 and measured.get_zorder() < clearance.get_zorder()
        values = np.asarray(measured.get_ydata())
        assert values.size > 100 and np.all(np.isfinite(values))
        # the noise, in pixels, is wider than the clearance's line that would hide it
        pixels = zoom.transData.transform(np.column_stack([measured.get_xdata(), values]))[:, 1]
        line_pixels = clearance.get_linewidth() * figure.dpi / 72
        assert np.std(pixels - zoom.transData.transform(np.column_stack(clearance.get_data()))[:, 1]) > line_pixels


def test_comparison_of_a_rig_run_draws_the_measured_height_once():
    run = _closed_loop_run("on the rig")
    run = dataclasses.replace(run, height_m=run.measured_m)
    figure = comparison_figure({"gs": run})
    assert [line.get_label() for line in figure.axes[1].get_lines()] == ["clearance: gain-scheduled", "reference"]


def _loop_table(frequency_hz: np.ndarray) -> ResultTable:
    """A Fig. 7 result table (fig7_slow's columns) with the given drive frequency."""
    columns = {"time": np.arange(frequency_hz.size) * 5e-4, SIMULATED.reference: np.full(frequency_hz.size, 1e-4),
               SIMULATED.measured: np.full(frequency_hz.size, 1e-4), SIMULATED.height: np.full(frequency_hz.size, 1e-4),
               EXCITATION_COMMAND: np.full(frequency_hz.size, 3e-6),
               SIMULATED.excitation: np.full(frequency_hz.size, 3e-6), SIMULATED.frequency: frequency_hz}
    units = ("s", "m", "m", "m", "m", "m", "Hz")
    return ResultTable(tuple(columns), units, np.column_stack(list(columns.values())))


def test_response_leaves_out_a_drive_frequency_nothing_moves():
    figure = response_figure(_loop_table(np.full(400, 28500.0)), response_panels(), title="fig7_slow")
    assert [axis.get_ylabel() for axis in figure.axes] == ["height [um]", "|a| [um]"]
    assert "ResonanceTracker.drive_frequency constant at 28500 Hz" in figure.get_suptitle()


def test_response_keeps_a_drive_frequency_that_moves():
    frequency = 28500.0 + np.r_[np.zeros(200), np.linspace(0.0, 57.0, 200)]
    figure = response_figure(_loop_table(frequency), response_panels(), title="fig7_slow")
    assert figure.axes[-1].get_ylabel() == "drive frequency change [Hz]"
    assert np.ptp(figure.axes[-1].get_lines()[0].get_ydata()) == pytest.approx(57.0)
    assert figure.get_suptitle() == "fig7_slow"


TABLE1_SWEEP = {"sweep": {"name": "t"}, "run": {"kind": "table1"},
                "grid": {"case": ["a", "c"], "excitation": [2e-6, 4e-6, 7e-6]},
                "random": {"draws": 2, "seed": 1, "mass": {"distribution": "uniform", "low": 0.1, "high": 0.2}}}


def _sweep_rows(spec) -> list[dict]:
    """One ok row per run, each metric a different function of the parameters."""
    rows = []
    for run in spec.runs():
        p = {**spec.settings, **run.parameters}
        row = {"status": "ok", **{f"param:{k}": v for k, v in run.parameters.items()}}
        row.update(delta_simplified=p["excitation"] * 1e4, delta_full=p["mass"] or 0.15,
                   error_percent=1.0 + (p["case"] == "c"))
        rows.append(row)
    return rows


def test_sweep_of_three_parameters_plots_each_metric_over_each():
    spec = parse_spec(TABLE1_SWEEP)
    rows = _sweep_rows(spec)
    figure = sweep_figure(spec, rows, list(TABLE1_METRICS))
    axes = [axis for axis in figure.axes if axis.get_visible()]
    assert len(axes) == len(TABLE1_METRICS) * 3
    assert [axis.get_xlabel() for axis in axes[:3]] == ["case", "excitation", "mass"]
    for axis in axes:
        dots = axis.get_lines()[0]
        x = np.asarray(dots.get_xdata(), dtype=float)
        if axis.get_xlabel() == "case":
            assert sorted({label.get_text() for label in axis.get_xticklabels()}) == ["a", "c"]
        else:
            np.testing.assert_allclose(x, [r[f"param:{axis.get_xlabel()}"] for r in rows])
    assert axes[-3].get_ylabel() == "error [%]"


def test_sweep_of_one_parameter_joins_its_runs():
    spec = parse_spec({**TABLE1_SWEEP, "grid": {"excitation": [2e-6, 4e-6, 7e-6]}, "random": {}})
    rows = _sweep_rows(spec)
    figure = sweep_figure(spec, rows, list(TABLE1_METRICS))
    axes = [axis for axis in figure.axes if axis.get_visible()]
    assert len(axes) == len(TABLE1_METRICS) and {axis.get_xlabel() for axis in axes} == {"excitation"}
    np.testing.assert_allclose(axes[0].get_lines()[1].get_xdata(), [2e-6, 4e-6, 7e-6])  # the line, in order


def test_calibration_legend_clear_of_the_data_and_eq17_smooth_on_a_coarse_grid():
    sigma = np.linspace(5.0, 500.0, 8)  # a time-marching run's few points
    K = np.tanh(sigma / 200.0) * 2.5 - 0.1  # below zero at small sigma, as the Fig. 3 form's K
    figure = calibration_figure(sigma, K, "time-marching", reference=paper_calibration())
    FigureCanvasAgg(figure).draw()
    axis = figure.axes[0]
    legend = figure.legends[0].get_window_extent()
    assert not legend.overlaps(axis.get_window_extent())
    eq17 = _line(axis, "measured fit, paper eq. (17)")
    assert len(eq17.get_xdata()) >= 100 and min(eq17.get_xdata()) < sigma[1]
