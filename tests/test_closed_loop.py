"""Closed loop of Figs. 9-10: noise, fast plant stepping vs. SimplifiedPlant.advance, metrics, comparison."""

import json
from types import SimpleNamespace

import numpy as np
import pytest

from nfal.errors import InvalidParameterError
from nfal.models.calibration import paper_calibration
from nfal.models.closed_loop import ClosedLoopRun, simulate_closed_loop
from nfal.models.reference import Staircase
from nfal.models.control_law import DiscreteControlLaw
from nfal.models.fixed_step_plant import FixedStepPlant
from nfal.models.measurement_noise import (MIN_CUTOFF_RATIO, ColouredNoise, biquad_filter, butterworth_biquad,
                                           coloured_noise)
from nfal.models.pid_design import design_schedule, fixed_design
from nfal.models.plant import PlantState, SimplifiedPlant
from nfal.models.rig import RigParameters
from nfal.models.stability import realizable_schedule
from nfal.models.step_metrics import level_reach, step_metrics, total_iae

PLANT = SimplifiedPlant(RigParameters(), paper_calibration())
REFERENCE = Staircase()
CONTROLLERS = {"gs": realizable_schedule(design_schedule()), "80": fixed_design(80e-6),
               "120": fixed_design(120e-6), "160": fixed_design(160e-6)}
NOISE = coloured_noise(REFERENCE.samples(2000.0), seed=0)


@pytest.fixture(scope="module")
def runs():
    return {noisy: {key: simulate_closed_loop(DiscreteControlLaw(g), PLANT, REFERENCE, NOISE if noisy else None)
                    for key, g in CONTROLLERS.items()} for noisy in (False, True)}


# --- noise ----------------------------------------------------------------------------------------
def test_noise_is_reproducible_with_std_a_third_of_the_peak_and_clipped():
    """Same seed, same record; std = peak / 3 (0.997 peak / 3 after clipping at 3 sigma), |n| <= peak, reached."""
    a, b = coloured_noise(40_000, seed=7), coloured_noise(40_000, seed=7)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, coloured_noise(40_000, seed=8))
    assert np.std(a) == pytest.approx(2e-6 / 3, rel=0.03)
    assert np.max(np.abs(a)) == 2e-6 and 0.001 < np.mean(np.abs(a) == 2e-6) < 0.006
    assert abs(np.mean(a)) < 0.1 * np.std(a)


def test_noise_scale_uses_the_filters_exact_variance():
    """sum h^2 of the 300 Hz / 2 kHz Butterworth equals the variance from the frequency response (Parseval)."""
    from scipy import signal
    noise = ColouredNoise()
    _, response = signal.sosfreqz(noise._sos, worN=2 ** 16, whole=True)
    assert noise.filter_gain ** 2 == pytest.approx(np.mean(np.abs(response) ** 2), rel=1e-9)
    assert noise.std_m == 2e-6 / 3


@pytest.mark.parametrize("cutoff, rate", [(300.0, 2000.0), (35.0, 2000.0), (1.0, 2000.0), (999.0, 2000.0),
                                          (300.0, 44100.0)])
def test_the_noise_filter_is_scipys_butterworth_run_as_sosfilt_runs_it(cutoff, rate):
    """The design within a few ulp of scipy.signal.butter's (1e-15 relative), the recursion sosfilt's to the bit,
    output and state."""
    from scipy import signal
    sos = butterworth_biquad(cutoff, rate)
    np.testing.assert_allclose(sos, signal.butter(2, cutoff, fs=rate, output="sos"), rtol=1e-15, atol=0)
    x, zi = np.random.default_rng(1).standard_normal(3000), np.array([[0.3, -0.2]])
    ours, theirs = biquad_filter(sos, x, zi), signal.sosfilt(sos, x, zi=zi)
    np.testing.assert_array_equal(ours[0], theirs[0])
    np.testing.assert_array_equal(ours[1], theirs[1])


@pytest.mark.parametrize("chunks", [[1] * 700, [3, 250, 1, 446], [256, 256, 188], [699, 1], [0, 700]],
                         ids=["one-by-one", "ragged", "blocks", "almost-all", "empty-first"])
def test_noise_streaming_is_bit_identical_to_the_record(chunks):
    stream = ColouredNoise(seed=11)
    parts = [np.array([stream.next_sample()]) if n == 1 else stream.take(n) for n in chunks]
    np.testing.assert_array_equal(np.concatenate(parts), coloured_noise(700, seed=11))


def test_noise_peek_and_state_restore():
    stream = ColouredNoise(seed=2)
    stream.take(300)
    saved = stream.get_state()
    assert stream.peek() == stream.peek() == stream.next_sample()
    rest = stream.take(500)
    restored = ColouredNoise(seed=99)
    restored.set_state(json.loads(json.dumps(saved)))  # the FMU serialises it as JSON
    restored.next_sample()
    np.testing.assert_array_equal(restored.take(500), rest)


def test_noise_is_coloured_at_300hz():
    """Welch spectrum: power at 800-1000 Hz is > 10x below that at 0-200 Hz (2nd-order roll-off above 300 Hz),
    and in 100 Hz bands up to 800 Hz it is the designed (peak/3)^2 |H|^2 / sum h^2 within 6 % (-3 dB at 300 Hz)."""
    from scipy import signal
    noise = coloured_noise(200_000, seed=1)
    f, p = signal.welch(noise, fs=2000.0, nperseg=1024)
    assert np.mean(p[f < 200]) > 10 * np.mean(p[f > 800])
    _, response = signal.sosfreqz(signal.butter(2, 300.0, fs=2000.0, output="sos"), worN=f, fs=2000.0)
    designed = 2.0 * (2e-6 / 3 / ColouredNoise().filter_gain) ** 2 * np.abs(response) ** 2 / 2000.0  # one-sided
    for low in range(0, 800, 100):
        band = (f >= low) & (f < low + 100)
        assert np.mean(p[band]) == pytest.approx(np.mean(designed[band]), rel=0.06), low
    assert abs(response[np.argmin(np.abs(f - 300.0))]) ** 2 == pytest.approx(0.5, rel=0.02)


def test_the_slowest_noise_filter_allowed_starts_in_its_steady_state():
    """At the lowest cut-off (the sample rate x MIN_CUTOFF_RATIO) the burn-in still brings the transient below 1e-12."""
    noise = ColouredNoise(cutoff_hz=2000.0 * MIN_CUTOFF_RATIO)
    pole_radius = float(np.max(np.abs(np.roots([1.0, *noise._sos[0, 4:]]))))
    assert pole_radius ** noise.burn_in <= 1e-12 and noise.burn_in == 62_192
    with pytest.raises(InvalidParameterError, match="at least 0.2 Hz"):
        ColouredNoise(cutoff_hz=0.999 * 2000.0 * MIN_CUTOFF_RATIO)


def test_noise_of_zero_peak_is_zero():
    assert not np.any(coloured_noise(50, peak_m=0.0))
    assert ColouredNoise(peak_m=0.0).next_sample() == 0.0


@pytest.mark.parametrize("kwargs", [{"samples": 0}, {"samples": 10, "cutoff_hz": 1500}, {"samples": 10, "peak_m": -1.0},
                                    {"samples": 2.5}, {"samples": 10, "seed": -1},
                                    {"samples": 10, "sample_rate_hz": 0.0}])
def test_bad_noise_settings_raise(kwargs):
    samples = kwargs.pop("samples")
    with pytest.raises(InvalidParameterError):
        coloured_noise(samples, **kwargs)


# --- plant stepping ---------------------------------------------------------------------------------
@pytest.mark.parametrize("height, velocity, excitation", [(60e-6, 0.0, 1.6e-6), (100e-6, -2e-3, 0.0),
                                                          (150e-6, 1e-3, 8e-6), (190e-6, 0.0, 5e-6)])
def test_fixed_step_advance_matches_adaptive_advance(height, velocity, excitation):
    state = PlantState(height, velocity)
    fast, exact = FixedStepPlant(PLANT).advance(state, excitation, 5e-4), PLANT.advance(state, excitation, 5e-4)
    assert fast.height == pytest.approx(exact.height, abs=2e-11)
    assert fast.velocity == pytest.approx(exact.velocity, abs=1e-7)


def test_fixed_step_run_matches_adaptive_run():
    """A 0.25 s two-level run: the two integrators agree within 1e-10 m all along."""
    reference = Staircase((100e-6, 130e-6), hold_s=0.15, lead_s=0.1)
    law = DiscreteControlLaw(CONTROLLERS["gs"])
    fast = simulate_closed_loop(law, PLANT, reference)
    exact = simulate_closed_loop(law, PLANT, reference, integrator="adaptive")
    assert np.max(np.abs(fast.height_m - exact.height_m)) < 1e-10


def test_fixed_step_hands_over_near_the_surface():
    state = PlantState(10e-6, -1e-3)
    np.testing.assert_equal(FixedStepPlant(PLANT).advance(state, 0.0, 5e-4), PLANT.advance(state, 0.0, 5e-4))


# --- metrics -------------------------------------------------------------------------------------
def test_metrics_of_a_known_first_order_response():
    """h = r0 + D (1 - exp(-t / tau)): rise 2.197 tau, no overshoot, 2 % settling 3.912 tau, IAE D tau."""
    tau, reference = 0.02, Staircase((100e-6, 140e-6), hold_s=0.5, lead_s=0.1)
    t = np.arange(reference.samples(20000.0)) / 20000.0
    after = np.clip(t - 0.1, 0, None)
    h = np.where(t < 0.1, 100e-6, 100e-6 + 40e-6 * (1 - np.exp(-after / tau)))
    run = ClosedLoopRun("test", t, reference(t), h, h, np.zeros_like(t))
    (m,) = step_metrics(run, reference)
    assert m.rise_time_s == pytest.approx(np.log(9) * tau, rel=1e-3)
    assert m.overshoot_percent == 0.0
    assert m.settling_time_s == pytest.approx(np.log(50) * tau, abs=1e-4)
    assert m.iae == pytest.approx(40e-6 * tau, rel=1e-2)
    assert m.noise_rms_m < 1e-11


def test_metrics_of_steps_with_unequal_holds():
    """Any step reference (levels, step times, duration), not only a staircase: each step judged over its own
    hold, up to the next step (the last up to the duration)."""
    tau, rate = 0.02, 20000.0
    steps = SimpleNamespace(levels_m=(100e-6, 140e-6, 120e-6), step_times_s=(0.1, 0.3), duration_s=0.8)
    t = np.arange(int(0.8 * rate)) / rate
    h = np.full_like(t, 100e-6)
    for start, (r0, r1) in zip(steps.step_times_s, [(100e-6, 140e-6), (140e-6, 120e-6)]):
        after = t >= start
        h[after] = r0 + (r1 - r0) * (1 - np.exp(-(t[after] - start) / tau))
    reference = np.select([t < 0.1, t < 0.3], [100e-6, 140e-6], 120e-6)
    up, down = step_metrics(ClosedLoopRun("test", t, reference, h, h, np.zeros_like(t)), steps)
    for m, size in ((up, 40e-6), (down, 20e-6)):
        assert m.rise_time_s == pytest.approx(np.log(9) * tau, rel=1e-3)
        assert m.settling_time_s == pytest.approx(np.log(50) * tau, abs=1e-4)
        assert m.iae == pytest.approx(size * tau, rel=1e-2)
    assert (up.to_m, down.to_m) == (140e-6, 120e-6)


def test_level_reach_within_the_band_or_crossed():
    """Reached: within 10 % of the step into the level, or across it, at some time of its hold (the first level's
    step from the run's first height)."""
    steps = SimpleNamespace(levels_m=(60e-6, 100e-6, 140e-6, 180e-6), step_times_s=(0.1, 0.2, 0.3), duration_s=0.4)
    t = np.arange(800) * 5e-4
    h = np.select([t < 0.1, t < 0.2, t < 0.3], [5e-6 + 0.5e-3 * t, 97e-6, np.where(np.arange(800) % 2, 130e-6, 150e-6)],
                  170e-6)  # 55 um of 60 after a 55 um lift; 3 um short; across 140 between samples; 10 um short
    reach = level_reach(ClosedLoopRun("test", t, t, h, h, t), steps)
    assert [r.reached for r in reach] == [True, True, True, False]
    assert reach[0].band_m == pytest.approx(5.5e-6) and reach[3].band_m == pytest.approx(4e-6)
    assert (reach[3].start_s, reach[3].end_s, reach[3].highest_m) == (0.3, 0.4, 170e-6)


# --- the comparison of Figs. 9-10 ------------------------------------------------------------------
@pytest.mark.slow  # five closed-loop runs, clean and noisy
def test_gain_scheduled_loop_has_zero_steady_state_error(runs):
    run = runs[False]["gs"]
    for start in REFERENCE.step_times_s + REFERENCE.hold_s:
        k = int(round(start * 2000)) - 1
        assert abs(run.height_m[k] - run.reference_m[k]) < 1e-9


@pytest.mark.slow  # five closed-loop runs, clean and noisy
@pytest.mark.parametrize("noisy", [False, True], ids=["clean", "noisy"])
def test_gain_scheduled_loop_has_the_smallest_iae(runs, noisy):
    iae = {key: total_iae(run) for key, run in runs[noisy].items()}
    assert min(iae, key=iae.get) == "gs", iae


@pytest.mark.slow  # five closed-loop runs, clean and noisy
def test_low_versus_high_design_trade_off(runs):
    """Paper: low-height designs transient-good but noisy; high-height designs quiet but oscillatory low down."""
    low = step_metrics(runs[True]["80"], REFERENCE)
    high = step_metrics(runs[True]["160"], REFERENCE)
    assert np.mean([m.noise_rms_m for m in low]) > 1.5 * np.mean([m.noise_rms_m for m in high])
    assert high[0].overshoot_percent > 3 * low[0].overshoot_percent  # 60 -> 100 um
    assert high[-1].overshoot_percent > 3 * low[-1].overshoot_percent  # 100 -> 60 um


def _saturated_run(tracking_time_s):
    """100 -> 200 -> 100 um with |a|max = 6 um: 200 um needs 6.2 um, so the loop sits in saturation for 1 s."""
    reference = Staircase((100e-6, 200e-6, 100e-6), hold_s=1.0, lead_s=0.05)
    law = DiscreteControlLaw(CONTROLLERS["120"], max_excitation_m=6e-6, tracking_time_s=tracking_time_s)
    return reference, simulate_closed_loop(law, PLANT, reference)


def test_saturating_step_recovers_without_windup():
    """Back-calculation: the command leaves the limit within 2 samples of the step back down, the loop settles
    (2 %) within 80 ms and ends on the reference; without it (T_t = 1e6 s) the wound-up integrator holds the
    command at the limit for > 20 samples and settling takes longer."""
    reference, run = _saturated_run(None)
    _, wound = _saturated_run(1e6)
    assert np.mean(run.excitation_m == 6e-6) > 0.4
    k = int(round(reference.step_times_s[1] * 2000))
    held = lambda r: int(np.argmax(r.excitation_m[k:] < 6e-6))  # noqa: E731
    assert held(run) <= 2 and held(wound) > 20
    down, down_wound = step_metrics(run, reference)[1], step_metrics(wound, reference)[1]
    assert down.settling_time_s < 0.08 and down_wound.settling_time_s > down.settling_time_s + 0.02
    assert abs(run.height_m[-1] - 100e-6) < 1e-9


def test_bad_noise_record_and_integrator_raise():
    law = DiscreteControlLaw(CONTROLLERS["120"])
    with pytest.raises(InvalidParameterError):
        simulate_closed_loop(law, PLANT, REFERENCE, np.zeros(10))
    with pytest.raises(InvalidParameterError):
        simulate_closed_loop(law, PLANT, REFERENCE, integrator="euler")


def test_fixed_step_advance_matches_adaptive_advance_over_random_states():
    """100 random free-flight states, 40-200 um, |v| <= 5 mm/s, |a| <= 10 um: within 1e-10 m per 0.5 ms step."""
    rng = np.random.default_rng(7)
    fast = FixedStepPlant(PLANT)
    errors = []
    for h, v, a in zip(rng.uniform(40e-6, 200e-6, 100), rng.uniform(-5e-3, 5e-3, 100), rng.uniform(0, 10e-6, 100)):
        state = PlantState(h, v)
        errors.append(abs(fast.advance(state, a, 5e-4).height - PLANT.advance(state, a, 5e-4).height))
    assert max(errors) < 1e-10


@pytest.mark.parametrize("stop_s, levels", [(None, 7), (3.7, 7), (0.7, 2), (1.29, 2), (1.3, 3), (0.5, None),
                                            (0.05, None)])
def test_staircase_completed_by(stop_s, levels):
    """The steps whose holds end by the stop time: what a shortened run can report metrics for."""
    cut = Staircase().completed_by(stop_s)
    assert (cut is None) if levels is None else (len(cut.levels_m) == levels
                                                 and cut.duration_s <= (stop_s or 3.7) + 1e-9)
