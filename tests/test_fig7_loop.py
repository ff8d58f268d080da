"""The Fig. 7 loop as FMUs wired by SSP, checked against the pure-Python loop of the controller issue."""

from pathlib import Path

import numpy as np
import pytest

from nfal.errors import InvalidParameterError
from nfal.fmus.base import VALUE_CACHE_ENV
from nfal.apps.fig7 import (DEFAULT_STAIRCASES, PURE_LOOP_PARAMETERS, SIMULATED, loop_metrics, matched_design,
                            pure_python_loop, reference_staircase, reynolds_law)
from nfal.models.reference import Staircase
from nfal.orchestration import compiled_exchange, run_structure

pytestmark = pytest.mark.slow  # closed loops of FMUs

ONE_STEP = Staircase((60e-6, 100e-6), hold_s=0.6, lead_s=0.1)
def run_fig7(archive, tmp_path, reference=ONE_STEP, **kwargs):
    return run_structure(archive, stop_time=reference.duration_s, step_size=5e-4,
                         inputs={"Controller.reference": reference}, out_dir=tmp_path, plot=False, progress=False,
                         **kwargs)


@pytest.mark.parametrize("seed", [0, 5])
def test_fmu_loop_reproduces_the_pure_python_loop(fig7_archives, tmp_path, seed):
    """Same seed, causal master: the FMU loop and closed_loop.py agree within 1e-12 m at every sample."""
    parameters = {**PURE_LOOP_PARAMETERS, "SensorChain.seed": seed}
    result = run_fig7(fig7_archives["fig7_slow"], tmp_path, parameters=parameters)
    reference = pure_python_loop(ONE_STEP, seed)
    fmu = result[SIMULATED.height][: reference.height_m.size]
    assert np.max(np.abs(fmu - reference.height_m)) < 1e-12


def test_default_loop_starts_bumpless_and_tracks(fig7_archives, tmp_path):
    """All blocks on (transducer lag, PLL, 2 kHz analog filter): no start transient, every hold reached."""
    result = run_fig7(fig7_archives["fig7_slow"], tmp_path)
    time, height = result.table().time, result[SIMULATED.height]
    lead = time < ONE_STEP.lead_s
    assert np.max(np.abs(height[lead] - 60e-6)) < 1e-6
    steady = time > ONE_STEP.duration_s - 0.2
    assert abs(np.mean(height[steady]) - 100e-6) < 0.5e-6
    metrics = loop_metrics(result.table(), ONE_STEP)
    assert metrics["steps"][0]["settling_time_s"] < 0.2


def test_jacobi_adds_delay_but_still_tracks(fig7_archives, tmp_path):
    """libcosim's scheme (one step of delay per feedthrough block) differs from causal, but not by much."""
    causal = run_fig7(fig7_archives["fig7_slow"], tmp_path / "causal")
    jacobi = run_fig7(fig7_archives["fig7_slow"], tmp_path / "jacobi", algorithm="jacobi")
    difference = np.max(np.abs(causal[SIMULATED.height] - jacobi[SIMULATED.height]))
    assert 1e-9 < difference < 10e-6


SHORT_REYNOLDS = Staircase((60e-6, 100e-6, 60e-6), hold_s=0.4, lead_s=0.1)
MEASURED_SHAPE = str(Path(__file__).resolve().parents[1] / "examples" / "shapes" / "vibrometer_scan.csv")


def test_the_reynolds_loop_is_the_same_to_the_bit_without_the_value_cache(fig7_archives, tmp_path, monkeypatch):
    """fmus/value_cache/, the ReynoldsPlant's compiled core and the master's compiled step change where the loop's
    work is done, not one bit of what it computes: the whole loop's results.csv, its FMUs stepped and read by the
    runtime and the master's kernel, and with NFAL_VALUE_CACHE=off and NFAL_COMPILED_EXCHANGE=off every call made
    from the master's Python through the slaves' Python."""
    runs = {}
    for switch in ("on", "off"):
        monkeypatch.setenv(VALUE_CACHE_ENV, switch)
        monkeypatch.setenv(compiled_exchange.SWITCH, switch)
        compiled_exchange.library.cache_clear()
        runs[switch] = run_fig7(fig7_archives["fig7_reynolds"], tmp_path / switch)
    compiled_exchange.library.cache_clear()
    timing = {switch: run.summary["timing"]["Plant"]["do_step_mean_us"] for switch, run in runs.items()}
    assert (tmp_path / "on" / "results.csv").read_bytes() == (tmp_path / "off" / "results.csv").read_bytes(), timing
    assert runs["on"].summary["steps_completed"] == 1400
    assert [run.summary["exchange_engine"] for run in runs.values()] == ["C", "Python"]


def hold_ends(table, reference: Staircase, window_s: float = 0.02) -> np.ndarray:
    """Mean true height over the last ``window_s`` of every hold after the first."""
    time, height = table.time, table[SIMULATED.height]
    ends = [*reference.step_times_s[1:], reference.duration_s]
    return np.array([np.mean(height[(time > end - window_s) & (time <= end)]) for end in ends])


@pytest.fixture(scope="module")
def slow_short(fig7_archives, tmp_path_factory):
    """fig7_slow running the Reynolds loop's law (its placement, cut-off and feedforward path) on its own plant."""
    return run_fig7(fig7_archives["fig7_slow"], tmp_path_factory.mktemp("slow"), SHORT_REYNOLDS,
                    parameters=reynolds_law())


@pytest.mark.parametrize("shape", ["paper", "piston", MEASURED_SHAPE])
def test_reynolds_loop_tracks_like_the_slow_loop(fig7_archives, tmp_path, slow_short, shape):
    """fig7_reynolds (harmonic-balance film, controller designed on the numerical K of the same form): every
    hold ends within 1 % of its reference, each step overshoots by at most 2 percentage points more than fig7_slow
    running the same law on the same steps (issue 29), and the drive never saturates long."""
    parameters = matched_design({"Plant.shape": shape})
    result = run_fig7(fig7_archives["fig7_reynolds"], tmp_path, SHORT_REYNOLDS, parameters=parameters)
    table = result.table()
    assert np.all(np.abs(hold_ends(table, SHORT_REYNOLDS) / SHORT_REYNOLDS.levels_m[1:] - 1) <= 0.01)
    metrics, slow = loop_metrics(table, SHORT_REYNOLDS), loop_metrics(slow_short.table(), SHORT_REYNOLDS)
    for step, baseline in zip(metrics["steps"], slow["steps"]):
        assert step["overshoot_percent"] <= baseline["overshoot_percent"] + 2.0
    assert metrics["saturation"] == []


@pytest.mark.parametrize("spec, structure, expected", [
    ("staircase", "fig7_reynolds", DEFAULT_STAIRCASES["fig7_reynolds"]),
    ("staircase", "fig7_slow", Staircase()),
    ("staircase:60e-6,90e-6:0.3:0.2", "fig7_slow", Staircase((60e-6, 90e-6), 0.3, 0.2)),
    ("reference.csv", "fig7_slow", None)])
def test_reference_staircase(spec, structure, expected):
    assert reference_staircase(spec, structure) == expected


def test_reference_staircase_rejects_a_bad_spec():
    with pytest.raises(InvalidParameterError, match="staircase:abc"):
        reference_staircase("staircase:abc", "fig7_reynolds")


def test_reference_staircase_in_micrometres_is_refused_before_the_run_with_the_unit_named():
    with pytest.raises(InvalidParameterError, match=r"--reference levels = \(60.0, 100.0\) is invalid: must be "
                       r"clearances within 1.0–1000.0 µm \(did you give µm or mm as m\?\)"):
        reference_staircase("staircase:60,100:0.2", "fig7_slow")


@pytest.mark.parametrize("given, added", [({"Plant.shape": "piston"}, "perturbation:piston"),
                                          ({"Plant.shape": "piston", "Controller.calibration": "paper"}, "paper"),
                                          ({}, None)])
def test_matched_design(given, added):
    assert matched_design(given).get("Controller.calibration") == added


def test_first_level_is_measured_apart_from_the_steps():
    """A rig's lift-off before the first step: its peak and IAE, and the steps' IAE, which add up to the total."""
    from nfal.apps.fig7 import first_level
    from nfal.models.closed_loop import ClosedLoopRun
    from nfal.models.step_metrics import total_iae

    reference = Staircase((60e-6, 100e-6), hold_s=0.5, lead_s=1.0)
    time = np.arange(3000) * 5e-4
    height = np.where(time < 0.5, 5e-6, np.where(time < 1.0, 62e-6, reference(time) - 1e-6))
    run = ClosedLoopRun("synthetic", time, reference(time), height, height, np.zeros_like(time))
    first = first_level(run, reference)
    assert first["peak_m"] == pytest.approx(62e-6)
    assert first["iae_m_s"] == pytest.approx(55e-6 * 0.5 + 2e-6 * 0.5, rel=1e-9)
    assert first["steps_iae_m_s"] == pytest.approx(1e-6 * 0.5, rel=1e-9)
    assert first["iae_m_s"] + first["steps_iae_m_s"] == pytest.approx(total_iae(run), rel=1e-12)
