"""Identification (``nfal identify``) in simulation: the numerics against known truths, the experiments against an
in-process simulated rig (no pty), and each fault stopping with its reason, the drive down and the data kept."""

from __future__ import annotations

import io

import numpy as np
import pytest
from simulated_rig import SimulatedRig

from nfal.cli import main
from nfal.apps.rig_identification import _run
from nfal.errors import ConvergenceError, DataFormatError, ExperimentError, InvalidParameterError
from nfal.apps.rig_analysis import analyse
from nfal.apps.rig_experiments import Experiments
from nfal.apps.sample_recorder import APPLIED, TIME, SampleRecorder
from nfal.models.calibration import PAPER_SIGMA_RANGE, PolynomialK, paper_calibration, rig_calibration_from_dict
from nfal.models.damping import DampingCorrection
from nfal.models.identification import (AMPLITUDE_TIME_CONSTANT_S, IdentificationPlan, StepFit, damping_table, fit_step,
                                        settled)
from nfal.models.plant import ExcessDamping, PlantState, SimplifiedPlant
from nfal.models.rig import RigParameters

RIG = RigParameters()
TRUTH = SimplifiedPlant(RIG, paper_calibration(), excess_damping=ExcessDamping.rig_like())
#: A shorter plan for the tests: the default equilibria (a quartic through 7 of them misses a K that is not a
#: quartic by 1.7 % in height, through 12 by 0.5 %); damping at 3 heights, 2 steps up and 2 down.
SHORT_PLAN = IdentificationPlan(damping_heights_m=(190e-6, 120e-6, 60e-6), steps=4)


# --- numerics ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("time_constant, expected", [(0.005, True), (1.0, False)])
def test_settled_tells_a_settled_height_from_a_slow_approach(time_constant, expected):
    times = np.arange(0, 1.0, 5e-4)
    noise = np.random.default_rng(1).normal(0, 0.67e-6, times.size)
    heights = 100e-6 + 20e-6 * np.exp(-times / time_constant) + noise
    assert settled(times, heights) is expected


def test_settled_needs_a_whole_window():
    times = np.arange(0, 0.3, 5e-4)
    assert not settled(times, np.full(times.size, 1e-4), window_s=0.4)


def _truth_step(height: float, up: bool, duration: float = 0.6) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The truth's noise-free response to a +-3 % step of |a| about ``height`` through the amplitude lag."""
    a = float(TRUTH.equilibrium_excitation(height))
    a1, a2 = (0.97 * a, 1.03 * a) if up else (1.03 * a, 0.97 * a)
    start = TRUTH.equilibrium_height(a1)
    lag = AMPLITUDE_TIME_CONSTANT_S
    path = TRUTH.simulate(duration, lambda t: a2 + (a1 - a2) * np.exp(-t / lag), PlantState(start), samples=1201)
    before = np.arange(-0.05, 0, 5e-4)
    return (np.concatenate([before, path.time]), np.concatenate([np.full(before.size, start), path.height]), a1, a2)


@pytest.mark.parametrize("height", [60e-6, 120e-6, 190e-6])
def test_a_step_pair_recovers_the_truths_damping_within_3_percent(height):
    fits = [fit_step(*_truth_step(height, up), RIG) for up in (True, False)]
    middle = np.mean([fit.height for fit in fits])
    assert np.mean([fit.factor for fit in fits]) == pytest.approx(ExcessDamping.rig_like().factor(middle), rel=0.03)
    assert all(fit.residual_rms < 0.03 * abs(fit.height_change) for fit in fits)  # linearisation error only


def test_a_step_the_wrong_way_is_refused():
    times, heights, a1, a2 = _truth_step(100e-6, up=True)
    with pytest.raises(ConvergenceError, match="wrong way"):
        fit_step(times, heights, a2, a1, RIG)


def test_the_damping_table_interpolates_monotonically_and_holds_its_ends():
    table = DampingCorrection(np.array([50e-6, 100e-6, 200e-6]), np.array([1.0, 1.5, 10.0]), np.array([0.9, 1.4, 9.0]),
                              np.array([1.1, 1.6, 11.0]))
    heights = np.linspace(50e-6, 200e-6, 50)
    assert np.all(np.diff(table.factor(heights)) > 0)
    assert table.factor(20e-6) == pytest.approx(1.0) and table.factor(300e-6) == pytest.approx(10.0)
    assert table.factor(100e-6) == pytest.approx(1.5)


@pytest.mark.parametrize("heights, factors", [([100e-6, 50e-6], [1.0, 2.0]), ([50e-6, 100e-6], [1.0, -2.0])])
def test_a_bad_damping_table_is_refused(heights, factors):
    with pytest.raises(DataFormatError):
        DampingCorrection(np.array(heights), np.array(factors), np.array(factors), np.array(factors))


def test_the_damping_interval_comes_from_the_steps_spread():
    fits = [StepFit(100e-6, 1.0, 1.0, 1e-6, factor, 0.0) for factor in (1.0, 1.2, 1.1, 1.3)]
    table = damping_table([fits, [StepFit(150e-6, 1.0, 1.0, 1e-6, factor, 0.0) for factor in (2.0, 2.2)]])
    assert table.factors[0] == pytest.approx(np.exp(np.mean(np.log([1.0, 1.2, 1.1, 1.3]))))
    assert table.factors_low[0] < 1.05 and table.factors_high[0] > 1.25
    with pytest.raises(InvalidParameterError, match="steps per height"):
        damping_table([fits[:1]])


@pytest.mark.parametrize("change, match", [
    ({"steps": 3}, "steps"), ({"step_fraction": 0.5}, "step_fraction"), ({"max_hold_s": 0.2}, "max_hold_s"),
    ({"equilibrium_heights_m": (50e-6, 60e-6)}, "equilibrium_heights_m = '50, 60 um' .* >= 5 distinct"),
    ({"equilibrium_heights_m": (100e-6,) * 6}, "equilibrium_heights_m = '100, 100 um' .* 3 % apart"),
    ({"equilibrium_heights_m": (60e-6, 80e-6, 100e-6, 150e-6, 151e-6, 190e-6)}, "'150, 151 um' .* 3 % apart"),
    ({"damping_heights_m": (100e-6,)}, "damping_heights_m = '100 um' .* >= 2 distinct"),
    ({"damping_heights_m": (80e-6, 120e-6, 80e-6)}, "damping_heights_m = '80, 80 um' .* 3 % apart"),
])
def test_a_bad_plan_is_refused(change, match):
    with pytest.raises(InvalidParameterError, match=match):
        IdentificationPlan(**change)


def test_heights_just_far_enough_apart_are_a_plan():
    plan = IdentificationPlan(equilibrium_heights_m=tuple(100e-6 * 1.031 ** np.arange(5)),
                              damping_heights_m=(80e-6, 83e-6))
    assert len(plan.equilibrium_heights_m) == 5 and plan.holds() == 5 + 2 * 7


def test_the_plan_states_its_duration():
    typical, longest = IdentificationPlan().duration_s()
    assert 20 < typical < 300 < longest


# --- the experiments against a simulated rig ---------------------------------------------------------------------
def _identify(truth: SimplifiedPlant, plan: IdentificationPlan = SHORT_PLAN, **rig_options):
    rig = SimulatedRig(truth, **rig_options)
    stream = io.StringIO()
    recorder = SampleRecorder(stream)
    experiments = Experiments(rig, plan, recorder, metres_per_volt=1e-7, max_voltage=100.0)
    equilibria, steps = experiments.equilibria(), experiments.damping_steps()
    experiments.ramp_down()
    return analyse(equilibria, steps, truth.rig, metres_per_volt=1e-7), recorder, stream


@pytest.fixture(scope="module")
def identified_other_truth():
    """A truth the plan was not designed for: heavier, other excess damping, and K eq. (17) times 0.9 + 5e-4 sigma
    (a quintic: the identification's quartic cannot match it exactly)."""
    tilted = np.polynomial.polynomial.polymul(paper_calibration().coefficients, [0.9, 5e-4])
    truth = SimplifiedPlant(RigParameters(mass=0.17), PolynomialK(tilted, PAPER_SIGMA_RANGE),
                            excess_damping=ExcessDamping(150e-6, 5.0))
    return truth, *_identify(truth)


@pytest.mark.slow
def test_the_identified_model_predicts_the_truths_equilibria_within_1_percent(identified_other_truth):
    truth, result, _, _ = identified_other_truth
    model = SimplifiedPlant(truth.rig, result.calibration.fit)
    for height in np.linspace(50e-6, 200e-6, 16):
        assert model.equilibrium_height(float(truth.equilibrium_excitation(height))) == pytest.approx(height, rel=0.01)


@pytest.mark.slow
def test_the_identified_damping_is_the_truths_within_15_percent(identified_other_truth):
    truth, result, _, _ = identified_other_truth
    table = result.damping
    assert table.heights_m.size == 3
    np.testing.assert_allclose(table.factors, truth.excess_damping.factor(table.heights_m), rtol=0.15)
    assert np.all(table.factors_low <= table.factors) and np.all(table.factors <= table.factors_high)


@pytest.mark.slow
def test_every_sample_is_streamed_to_the_csv_and_the_drive_ends_at_zero(identified_other_truth):
    _, result, recorder, stream = identified_other_truth
    lines = stream.getvalue().splitlines()
    assert lines[0].startswith("rig_time_s,height_m") and len(lines) == recorder.count + 1
    assert recorder.last(APPLIED) == 0.0
    document = result.document({"port": "test"})
    assert set(document["damping"]) == {"heights_m", "factors", "factors_low", "factors_high"}
    assert document["kind"] == "polynomial" and document["provenance"] == {"port": "test"}


@pytest.mark.slow
def test_the_identified_file_is_refused_on_another_rig(identified_other_truth):
    """The file records the rig it was identified on: a design for another load refuses it."""
    truth, result, _, _ = identified_other_truth
    loaded = rig_calibration_from_dict(result.document({}))
    loaded.check_rig(truth.rig)
    with pytest.raises(DataFormatError, match="another rig"):
        loaded.check_rig(truth.rig.replace(mass=truth.rig.mass * 1.2))


def _drifting(t: float) -> float:
    return 1.0 + 0.05 * t  # the transducer's gain creeping up 5 % a second (a rig warming up)


@pytest.mark.parametrize("options, match", [
    ({"max_voltage": 8.0}, "cannot lift the load"),
    ({"silent_after_s": 1.0}, "link lost"),
    ({"gain": _drifting}, "did not settle"),
    ({"gain": lambda t: 1.0 if t < 1.5 else 0.0}, "touched down"),
    ({"tripped_after_s": 1.5}, "watchdog tripped"),
])
@pytest.mark.slow  # identifications against a simulated rig
def test_a_fault_stops_with_its_reason_keeps_the_data_and_ramps_down(options, match):
    plan = IdentificationPlan(SHORT_PLAN.equilibrium_heights_m, SHORT_PLAN.damping_heights_m, steps=2, max_hold_s=1.0)
    rig = SimulatedRig(TRUTH, **options)
    recorder = SampleRecorder(io.StringIO())
    experiments = Experiments(rig, plan, recorder, metres_per_volt=1e-7, max_voltage=options.get("max_voltage", 100.0))
    with pytest.raises(ExperimentError, match=match):
        experiments.equilibria()
    kept = recorder.count
    assert kept > 1000
    link_alive = "silent_after_s" not in options
    assert experiments.ramp_down() is link_alive
    if link_alive:
        assert recorder.last(APPLIED) == 0.0 and recorder.count > kept


class LateRig(SimulatedRig):
    """A host that reads late: each exchange returns the samples measured before its DRIVE arrived."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._pending: list = []

    def exchange(self, voltage: float):
        answered, self._pending = self._pending, super().exchange(voltage)
        return answered or self._pending


def test_the_ramp_holds_0_v_until_the_rig_says_it_applies_it():
    """A caller's STOP comes after the rig has measured at 0 V, even when the samples come one DRIVE late."""
    rig = LateRig(TRUTH, noise_peak_m=0.0)
    experiments = Experiments(rig, SHORT_PLAN, SampleRecorder(io.StringIO()), metres_per_volt=1e-7, max_voltage=100.0)
    experiments.voltage = 40.0
    assert experiments.ramp_down()
    assert rig.exchange(0.0)[-1].applied_voltage_v == 0.0  # what the rig measured last before a STOP
    assert experiments.recorder.last(APPLIED) == 0.0


@pytest.mark.slow  # identifications against a simulated rig
def test_ctrl_c_ramps_the_drive_down_keeps_the_data_and_says_where(tmp_path):
    rig = SimulatedRig(TRUTH, interrupt_at_s=1.0)
    recorder = SampleRecorder(io.StringIO())
    experiments = Experiments(rig, SHORT_PLAN, recorder, metres_per_volt=1e-7, max_voltage=100.0)
    with pytest.raises(KeyboardInterrupt, match="^interrupted; the drive ramped down; STOP sent; every sample so far "
                       "is in"):
        _run(experiments, rig, tmp_path / "raw.csv")
    assert recorder.last(APPLIED) == 0.0 and recorder.last(TIME) > 1.0


# --- the command line --------------------------------------------------------------------------------------------
def test_dry_run_prints_the_plan_and_its_duration(capsys):
    assert main(["identify", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "12 heights" in out and "8 heights" in out and "s of rig time" in out


@pytest.mark.parametrize("argv, match", [(["identify"], "--port"),
                                         (["identify", "--dry-run", "--steps", "3"], "--steps"),
                                         (["identify", "--port", "/nonexistent/port"], "cannot open")])
def test_bad_input_exits_2_with_the_reason(argv, match, capsys):
    assert main(argv) == 2
    assert match in capsys.readouterr().err


@pytest.mark.parametrize("plan, match", [
    (["--equilibria", "1e-4,1e-4,1e-4,1e-4,1e-4,1e-4"], "--equilibria = '100, 100 um' is invalid"),
    (["--damping-heights", "1e-4"], "--damping-heights = '100 um' is invalid: must be >= 2 distinct heights"),
    (["--equilibria", "60e-6:180e-6:4"], "--equilibria = '60, 100, 140, 180 um' is invalid: must be >= 5"),
    (["--damping-heights", "5e-5:2e-4:100000"], "--damping-heights = '50, 50.0015 um' is invalid"),  # the grid
    (["--steps", "1000"],
     "the plan takes about 1.1 h of rig time (up to 11.2 h), more than 1 h: give --accept-long-plan"),
    (["--steps", "10000", "--accept-long-plan"], "the plan's longest run (every move and hold to its limit) is "
                                                 "400,280 s of samples, 31.3 GiB held in memory; at most 8 GiB"),
])
@pytest.mark.parametrize("mode", [["--dry-run"], ["--port", "/nonexistent/port", "--out", "rig.json"]])
def test_a_bad_or_long_plan_is_refused_before_the_port_opens(plan, match, mode, capsys, tmp_path,
                                                              monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["identify", *mode, *plan]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"nfal identify: error: {match}") and err.count("\n") == 1
    assert not list(tmp_path.iterdir())  # no port opened, no raw data begun


def test_a_long_plan_runs_when_accepted_and_the_dry_run_prints_it_as_json(capsys):
    import json

    assert main(["identify", "--dry-run", "--json", "--steps", "1000", "--accept-long-plan"]) == 0
    plan = json.loads(capsys.readouterr().out)
    assert plan["steps"] == 1000 and len(plan["damping_heights_m"]) == 8
    assert 3600 < plan["duration_s"]["typical"] < plan["duration_s"]["longest"]
