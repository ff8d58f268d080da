"""The resonance-tracking PLL (models/pll.py): detector, gain design, the acceptance check under drift, lock."""

import dataclasses
import math

import numpy as np
import pytest

from nfal.errors import InvalidParameterError
from nfal.models.pll import (PhaseLockedLoop, PllGains, PllState, ResonanceTracker, design_gains, drift_ramp,
                             phase_error, simulate_tracking, wrap_phase)
from nfal.models.transducer import Transducer

TRANSDUCER = Transducer()  # 28.5 kHz, Q = 500, 0.1 um/V
F_R = TRANSDUCER.resonance_frequency_hz
VOLTAGE = 100.0  # -> 10 um at resonance
RESONANT_M = 0.1e-6 * VOLTAGE
DRIFT_HZ = 0.002 * F_R  # 0.2 % of the drive frequency: 57 Hz
MODES = pytest.mark.parametrize("dynamics", [True, False], ids=["dynamic", "quasi-static"])


def tracker(dynamics=True, **options):
    pll = PhaseLockedLoop.designed(TRANSDUCER, quasi_static=not dynamics, **options)
    return ResonanceTracker(TRANSDUCER, pll, dynamics=dynamics)


@pytest.mark.parametrize("angle, wrapped", [(0.0, 0.0), (math.pi, math.pi), (-math.pi, math.pi),
                                            (3 * math.pi / 2, -math.pi / 2), (-5 * math.pi / 2, -math.pi / 2),
                                            (7.0, 7.0 - 2 * math.pi)])
def test_wrap_phase(angle, wrapped):
    assert wrap_phase(angle) == pytest.approx(wrapped, abs=1e-12)


@pytest.mark.parametrize("detuning_hz, sign", [(-20.0, 1), (0.0, 0), (20.0, -1), (-2000.0, 1), (2000.0, -1)])
def test_phase_detector_sign(detuning_hz, sign):
    """Below resonance the displacement lags by less than 90 deg: e > 0, the loop must raise f."""
    error = phase_error(TRANSDUCER.steady_state(1.0, F_R + detuning_hz))
    assert np.sign(round(error, 12)) == sign and abs(error) < math.pi / 2


@MODES
def test_gains_cancel_the_transducer_pole(dynamics):
    """(P2): K_p / (K_p + K_i T) = exp(-T / tau) (0 for the quasi-static transducer)."""
    pll = tracker(dynamics).pll
    p, i, t = pll.gains.proportional_hz_per_rad, pll.gains.integral_hz_per_rad_s, pll.period_s
    expected = math.exp(-t / TRANSDUCER.time_constant_s()) if dynamics else 0.0
    assert p / (p + i * t) == pytest.approx(expected, abs=1e-15)


@MODES
def test_small_step_response_is_the_designed_first_order_loop(dynamics):
    """A 0.5 Hz step of the resonance at t = T: f_k - f_0 = 0.5 (1 - c^(k - d)), c = exp(-2 pi B T), d the loop's
    delay (2 samples with the envelope dynamics, 1 quasi-static); within 1e-4 of the step (linearisation)."""
    run = simulate_tracking(tracker(dynamics), 0.3, voltage_v=VOLTAGE,
                            resonance_shift_hz=lambda t: 0.5 if t > 1e-4 else 0.0)
    k = np.arange(run.time_s.size)
    delay = 2 if dynamics else 1
    c = math.exp(-2 * math.pi * 10.0 / 2000.0)
    ideal = np.where(k >= delay, 0.5 * (1 - c ** (k - delay + 1)), 0.0)
    np.testing.assert_allclose(run.drive_frequency_hz - F_R, ideal, rtol=0, atol=0.5e-4)


@MODES
@pytest.mark.parametrize("enabled", [True, False], ids=["pll", "fixed"])
def test_acceptance_pll_keeps_the_amplitude_under_0p2_percent_drift(dynamics, enabled):
    """The issue's acceptance check: the resonance ramps by 0.2 % of the drive frequency over 0.5 s, then holds,
    at 100 V. With the PLL ||a|| stays within 1 % of its resonant value after lock (measured: 0.2 %); at a fixed
    frequency it ends below half of it (0.448 at Q = 500)."""
    run = simulate_tracking(tracker(dynamics, enabled=enabled), 1.2, voltage_v=VOLTAGE,
                            resonance_shift_hz=drift_ramp(DRIFT_HZ, 0.5, start_s=0.1))
    ratio = run.excitation_amplitude_m / RESONANT_M
    if enabled:
        assert run.locked.any()
        after_lock = ratio[np.argmax(run.locked):]
        assert np.all(np.abs(after_lock - 1.0) < 0.01), np.min(after_lock)
        assert run.locked[-1] and run.drive_frequency_hz[-1] == pytest.approx(F_R + DRIFT_HZ, abs=1e-6)
    else:
        assert not run.locked.any()
        assert np.all(run.drive_frequency_hz == F_R)
        assert ratio[-1] < 0.5


@MODES
def test_pull_in_and_lock_from_0p2_percent_detuning(dynamics):
    """Starting 57 Hz (2 half-power bandwidths) off resonance: locked within 80 ms, and stays locked with
    ||a|| within 1 % from then on (measured: 72 ms dynamic, 66 ms quasi-static)."""
    run = simulate_tracking(tracker(dynamics), 0.4, voltage_v=VOLTAGE, resonance_shift_hz=DRIFT_HZ)
    first = int(np.argmax(run.locked))
    assert run.locked[first] and run.time_s[first] < 0.08
    assert run.locked[first:].all()
    assert np.all(np.abs(run.excitation_amplitude_m[first:] / RESONANT_M - 1) < 0.01)


def test_ramp_is_followed_with_the_designed_lag():
    """A ramp of r = 114 Hz/s is followed r / (2 pi B) = 1.8 Hz behind (type-1 loop), within 5 %."""
    rate = DRIFT_HZ / 0.5
    run = simulate_tracking(tracker(), 0.5, voltage_v=VOLTAGE, resonance_shift_hz=drift_ramp(DRIFT_HZ, 0.5))
    lag = (F_R + run.resonance_shift_hz - run.drive_frequency_hz)[-100:]
    assert np.all(np.abs(lag / (rate / (2 * math.pi * 10.0)) - 1) < 0.05)


def test_disabled_pll_measures_but_holds_the_frequency():
    pll = PhaseLockedLoop.designed(TRANSDUCER, enabled=False)
    state = pll.step(pll.initial_state(), TRANSDUCER.steady_state(1.0, F_R, 20.0))
    assert state.drive_frequency_hz == F_R and not state.locked
    assert state.phase_error_rad == pytest.approx(math.atan(2 * 500 * 20 / F_R), rel=1e-3)


def test_no_drive_holds_the_loop_unlocked():
    """At 0 V the phase is not measurable: frequency and integrator hold, e = 0, unlocked (no NaN)."""
    pll = PhaseLockedLoop.designed(TRANSDUCER)
    before = PllState(F_R + 3.0, 3.0, 0.05, 20, True)
    after = pll.step(before, 0j)
    assert (after.drive_frequency_hz, after.integrator_hz, after.phase_error_rad, after.locked) == \
        (F_R + 3.0, 3.0, 0.0, False)
    run = simulate_tracking(tracker(), 0.05, voltage_v=0.0, resonance_shift_hz=20.0)
    assert np.all(run.drive_frequency_hz == F_R) and np.all(run.excitation_amplitude_m == 0) and not run.locked.any()


def test_pull_range_clamps_without_windup():
    """A shift beyond the pull range (1 % = 285 Hz) parks the drive at the limit; when the resonance comes back to
    57 Hz the loop slews the 228 Hz back at once and relocks within 0.2 s (measured 0.143 s; the integral held at
    the limit, not wound up by 0.3 s of saturated phase error)."""
    run = simulate_tracking(tracker(), 0.6, voltage_v=VOLTAGE,
                            resonance_shift_hz=lambda t: 400.0 if t < 0.3 else DRIFT_HZ)
    before = run.time_s < 0.3
    assert np.max(run.drive_frequency_hz) == pytest.approx(F_R + 285.0, abs=1e-9)
    assert run.drive_frequency_hz[before][-1] == pytest.approx(F_R + 285.0, abs=1e-9)
    relock = run.time_s[np.argmax(run.locked & ~before)] - 0.3
    assert 0 < relock < 0.2
    assert run.drive_frequency_hz[~before][2] < F_R + 285.0 - 1.0  # leaves the limit within the loop delay


def test_step_is_pure():
    pll = PhaseLockedLoop.designed(TRANSDUCER)
    state = pll.initial_state()
    copy = dataclasses.replace(state)
    first = pll.step(state, TRANSDUCER.steady_state(1.0, F_R, 10.0))
    assert state == copy and pll.step(state, TRANSDUCER.steady_state(1.0, F_R, 10.0)) == first


@pytest.mark.parametrize("kwargs", [{"bandwidth_hz": 200.0}, {"bandwidth_hz": 0.0}, {"sample_rate_hz": -1.0},
                                    {"lock_threshold_rad": 2.0}, {"lock_samples": 0}, {"pull_range_hz": 30000.0},
                                    {"enabled": "yes"}])
def test_bad_pll_settings_raise(kwargs):
    with pytest.raises(InvalidParameterError):
        PhaseLockedLoop.designed(TRANSDUCER, **kwargs)


@pytest.mark.parametrize("args", [(10.0, 2000.0, 0.0, 0.005), (10.0, 2000.0, 0.035, -1.0), (10.0, 0.0, 0.035, 0.005)])
def test_bad_design_inputs_raise(args):
    with pytest.raises(InvalidParameterError):
        design_gains(*args)


def test_bad_gains_and_envelope_raise():
    with pytest.raises(InvalidParameterError):
        PhaseLockedLoop(F_R, PllGains(-1.0, 10.0))
    pll = PhaseLockedLoop.designed(TRANSDUCER)
    with pytest.raises(InvalidParameterError):
        pll.step(pll.initial_state(), complex("nan"))
    with pytest.raises(InvalidParameterError):
        simulate_tracking(tracker(), 0.1, step_s=3e-4)  # does not divide the PLL period
