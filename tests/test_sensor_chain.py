"""Sensor chain (models/sensor_chain.py): the pure-Python loop's measurement, the analog filter, sampling,
quantisation."""

import math

import numpy as np
import pytest

from nfal.errors import InvalidParameterError
from nfal.models.measurement_noise import ColouredNoise, coloured_noise
from nfal.models.sensor_chain import SensorChain


def run_chain(chain, heights, dt, per_sample=1):
    """Measurements at every communication point (step dt), sampling every ``per_sample`` points."""
    state, out = chain.initial_state(heights[0]), []
    for k, height in enumerate(heights):
        at_sample = k % per_sample == 0
        out.append(chain.output(state, height, at_sample=at_sample))
        state = chain.advance(state, height, dt, at_sample=at_sample)
    return np.array(out)


@pytest.mark.parametrize("seed", [0, 5])
def test_without_filter_and_quantiser_it_is_the_closed_loop_measurement(seed):
    """analog_cutoff = 0, resolution = 0: m_k = h_k + coloured_noise(...)[k], bit for bit (models/closed_loop.py)."""
    heights = 60e-6 + 20e-6 * np.sin(np.arange(1500) * 0.01)
    measured = run_chain(SensorChain(analog_cutoff_hz=0.0, seed=seed), heights, 5e-4)
    np.testing.assert_array_equal(measured, heights + coloured_noise(1500, seed=seed))


def test_filter_starts_in_steady_state_and_has_unit_dc_gain():
    measured = run_chain(SensorChain(noise_peak_m=0.0), np.full(400, 87e-6), 5e-4)
    np.testing.assert_allclose(measured, 87e-6, rtol=1e-12)
    step = run_chain(SensorChain(noise_peak_m=0.0), np.r_[60e-6, np.full(400, 90e-6)], 5e-4)
    assert step[-1] == pytest.approx(90e-6, rel=1e-12)


@pytest.mark.parametrize("ratio", [0.1, 1.0, 3.0])
def test_analog_filter_gain_through_time_stepping(ratio):
    """A sine at ratio x 2 kHz, stepped at 100 kHz with the input held (ZOH, sampled mid-step): the steady-state
    gain is |H| sinc(f dt), and |H(f_c)| = 1/sqrt(2) (-3 dB at the cut-off), within 1e-3."""
    dt, frequency = 1e-5, 2000.0 * ratio
    chain = SensorChain(noise_peak_m=0.0, sample_rate_hz=1 / dt)
    t = np.arange(3000) * dt
    measured = run_chain(chain, 1e-6 * np.sin(2 * math.pi * frequency * (t + dt / 2)), dt)[1000:]
    basis = np.column_stack([np.sin(2 * math.pi * frequency * t[1000:]), np.cos(2 * math.pi * frequency * t[1000:])])
    gain = np.hypot(*np.linalg.lstsq(basis, measured, rcond=None)[0]) / 1e-6
    expected = abs(chain.frequency_response(frequency)) * np.sinc(frequency * dt)
    assert gain == pytest.approx(expected, rel=1e-3)
    if ratio == 1.0:
        assert 20 * math.log10(abs(chain.frequency_response(frequency))) == pytest.approx(-3.0103, abs=1e-4)


def test_filter_step_is_exact_for_held_input():
    """Two steps of dt equal one step of 2 dt (ZOH discretisation by the matrix exponential)."""
    chain = SensorChain(noise_peak_m=0.0)
    start = chain.initial_state(60e-6)
    one = chain.advance(start, 80e-6, 5e-4, at_sample=False)
    two = chain.advance(chain.advance(start, 80e-6, 2.5e-4, at_sample=False), 80e-6, 2.5e-4, at_sample=False)
    np.testing.assert_allclose(two.filter_m, one.filter_m, rtol=1e-12, atol=1e-20)


def test_measurement_holds_between_sample_instants():
    """Communication step T/4: the output changes only at every 4th point (the sample instants)."""
    heights = 60e-6 + 1e-6 * np.arange(40)
    measured = run_chain(SensorChain(analog_cutoff_hz=0.0, noise_peak_m=0.0), heights, 1.25e-4, per_sample=4)
    np.testing.assert_array_equal(measured, np.repeat(heights[::4], 4))


@pytest.mark.parametrize("resolution", [1e-7, 1e-6, 2.5e-6])
def test_quantisation_on_the_grid_within_half_a_step(resolution):
    heights = np.linspace(50e-6, 70e-6, 401)
    measured = run_chain(SensorChain(analog_cutoff_hz=0.0, noise_peak_m=0.0, resolution_m=resolution), heights, 5e-4)
    np.testing.assert_allclose(measured / resolution, np.round(measured / resolution), atol=1e-9)
    assert np.max(np.abs(measured - heights)) <= resolution / 2 * (1 + 1e-9)
    assert len(np.unique(np.round(measured / resolution))) == pytest.approx(20e-6 / resolution + 1, abs=1)


def test_state_save_and_restore_repeats_the_run():
    chain = SensorChain(seed=3)
    state = chain.initial_state(60e-6)
    for _ in range(37):
        state = chain.advance(state, 61e-6, 5e-4, at_sample=True)
    saved = chain.get_state(state)

    def more(s):
        out = []
        for _ in range(300):
            out.append(chain.output(s, 62e-6, at_sample=True))
            s = chain.advance(s, 62e-6, 5e-4, at_sample=True)
        return out

    first = more(state)
    assert more(chain.set_state(saved)) == first


@pytest.mark.parametrize("kwargs", [{"analog_cutoff_hz": -1.0}, {"resolution_m": float("nan")}, {"sample_rate_hz": 0.0},
                                    {"noise_cutoff_hz": 1500.0}, {"noise_cutoff_hz": 0.19}, {"seed": -2},
                                    {"noise_peak_m": -1e-6}])
def test_bad_settings_raise(kwargs):
    with pytest.raises(InvalidParameterError):
        SensorChain(**kwargs)


@pytest.mark.parametrize("kwargs", [{"noise_peak_m": 1.0}, {"resolution_m": 0.1}])
def test_lengths_in_micrometres_given_as_metres_are_refused(kwargs):
    with pytest.raises(InvalidParameterError, match=r"at most 0.005 m for a levitation rig \(did you give µm"):
        SensorChain(**kwargs)


def test_bad_inputs_raise():
    chain = SensorChain()
    state = chain.initial_state(60e-6)
    with pytest.raises(InvalidParameterError):
        chain.output(state, float("nan"), at_sample=True)
    with pytest.raises(InvalidParameterError):
        chain.advance(state, 60e-6, 0.0, at_sample=True)
    with pytest.raises(InvalidParameterError):
        chain.set_state({"sensor": {}})


@pytest.mark.parametrize("height", [float("nan"), 1e300, "abc"])
def test_an_impossible_true_height_is_refused_by_the_model_itself(height):
    chain = SensorChain()
    state = chain.initial_state(100e-6)
    for call in (lambda: chain.output(state, height, at_sample=True),
                 lambda: chain.advance(state, height, 5e-4, at_sample=True)):
        with pytest.raises(InvalidParameterError, match="true_height"):
            call()


def test_a_noiseless_streams_state_restores_after_samples():
    """peak 0: no block and no position in it, so a state taken after samples restores (it was refused: position 300
    beyond an empty block, which failed a SensorChain FMU's fmi2SetFMUstate with its noise off)."""
    stream = ColouredNoise(peak_m=0.0)
    assert [stream.next_sample() for _ in range(300)] == [0.0] * 300
    copy = ColouredNoise(peak_m=0.0)
    copy.set_state(stream.get_state())
    assert copy.next_sample() == 0.0
