"""The kernels of the ResonanceTracker's and SensorChain's compiled cores (models/tracker_kernels.py,
models/sensor_core.py, models/clock_kernels.py) give the same bits compiled as in Python, where the models call them:
a core steps where the slave's Python would, and neither may tell which ran."""

import cmath
import math

import numpy as np
import pytest

from nfal.models import clock_kernels, sensor_core, tracker_core, tracker_kernels

pytestmark = pytest.mark.slow  # numba's start

tracker_core.step_address()  # compiles (or loads) the kernels: what these tests check is compiled code
sensor_core.step_address()
RANDOM = np.random.default_rng(7)
N = 20000


def test_the_envelope_step_is_the_same_compiled():
    """Across drives, detunings (a drifting resonance: the squares of nearby frequencies) and step sizes."""
    f_r = 28500.0
    for k in range(N):
        args = (RANDOM.normal(0, 5e-6), RANDOM.normal(0, 5e-6), RANDOM.uniform(0, 200), f_r + RANDOM.normal(0, 60),
                f_r + RANDOM.normal(0, 60), 500.0, 0.1e-6, 5e-4 * RANDOM.integers(1, 3))
        assert tracker_kernels.envelope_step.py_func(*args) == tracker_kernels.envelope_step(*args), (k, args)


def test_the_pll_sample_and_phase_detector_are_the_same_compiled():
    constants = (28500.0, 3.1, 2200.0, 5e-4, 285.0, 0.1, 20, 1e-12, True)
    for k in range(N):
        re, im = RANDOM.normal(0, 5e-6), RANDOM.normal(0, 5e-6)
        state = (28500.0 + RANDOM.normal(0, 50), RANDOM.normal(0, 20), int(RANDOM.integers(0, 21)), bool(k % 2))
        assert tracker_kernels.pll_sample.py_func(re, im, *state, *constants) == \
            tracker_kernels.pll_sample(re, im, *state, *constants), k
        assert tracker_kernels.phase_error.py_func(re, im) == tracker_kernels.phase_error(re, im)


def test_the_phase_detector_wraps_as_math_remainder():
    """arg A + pi/2 lies in [-pi/2, 3 pi/2]: there x - 2 pi, where x > pi, is remainder's wrap to the bit."""
    points = [*zip(RANDOM.normal(0, 1, N), RANDOM.normal(0, 1, N)), (-1.0, 0.0), (-1.0, -0.0), (0.0, 1.0),
              (0.0, -1.0), (1.0, 0.0), (-1.0, 1e-300)]
    for re, im in points:
        wrapped = math.remainder(cmath.phase(complex(re, im)) + math.pi / 2, 2 * math.pi)  # the detector before
        expected = math.pi if wrapped == -math.pi else wrapped
        assert tracker_kernels.phase_error.py_func(re, im) == tracker_kernels.phase_error(re, im) == expected, (re, im)


def test_the_sensor_filter_and_the_clock_are_the_same_compiled():
    for k in range(N):
        args = tuple(RANDOM.normal(0, 1, 9))
        assert sensor_core.filter_step.py_func(*args) == sensor_core.filter_step(*args)
        t, period = RANDOM.integers(0, 10000) * 5e-4 + RANDOM.choice([0.0, 1e-15, 2e-4]), 5e-4 * RANDOM.integers(1, 5)
        assert clock_kernels.sample_index.py_func(t, 0.0, period, 1e-9) == clock_kernels.sample_index(t, 0.0, period,
                                                                                                     1e-9)
        step = period / RANDOM.choice([1.0, 2.0, 3.0, 2.5, 0.5])
        assert clock_kernels.divides.py_func(period, step, 1e-9) == clock_kernels.divides(period, step, 1e-9)
