"""The SensorChain's step as a C function, behind its analog filter: what the FMU runtime's value cache calls for its
doStep without entering Python (fmus/value_cache/, docs/cosimulation.md, "the value cache").

:func:`step_address` is a numba ``cfunc`` with :mod:`~nfal.models.plant_core`'s signature. ``data`` is :func:`pack`'s
array: the buffer's slots, the checks the slave makes, the sample clock, the filter's discretisation for the step
size it was made for, the state (filter, noise, held measurement) and the noise block being read, which the core
keeps. It does what :meth:`SensorChain.advance <nfal.models.sensor_chain.SensorChain.advance>` and the measurement's
read after it do (the filter's update is :func:`filter_step`, which ``advance`` calls too) and answers 0; a height
or a step size the slave refuses or that needs a new discretisation, a quantiser, or a noise block used up, it
leaves to the slave's Python (answer 1), which steps, says why if it fails, and draws the next block.
"""

from __future__ import annotations

import math

import numpy as np

from . import clock_kernels, jit
from .measurement_noise import BLOCK

#: The files whose kernels the compiled core holds (part of its numba cache key, models/numba_cache.py).
KERNEL_DEPENDENCIES = ("clock_kernels.py",)

#: ``data``: the buffer's slots (true height, measured height, the time the core stepped to), the largest clearance,
#: the sample clock's tolerance, start and period, the step size the discretisation is for and its tolerance, the
#: discretisation (phi00, phi01, phi10, phi11, gamma0, gamma1), whether there is noise; the state (filter height and
#: rate, noise, held measurement, the noise block's position and size); the block.
_SLOTS, _MAX_HEIGHT, _TOLERANCE, _START, _PERIOD, _STEP, _STEP_TOLERANCE, _PHI, _NOISY = 0, 3, 4, 5, 6, 7, 8, 9, 15
STATE = 16
STATE_SIZE = 6
BLOCK_START = STATE + STATE_SIZE


@jit.kernel
def filter_step(height, rate, u, p00, p01, p10, p11, g0, g1):
    """The analog filter's state (height [m], rate [m/s]) after a step with the input ``u`` held, by its exact
    discretisation phi, gamma."""
    return p00 * height + p01 * rate + g0 * u, p10 * height + p11 * rate + g1 * u


def pack(slots: tuple[int, ...], max_height: float, tolerance: float, start: float, period: float,
         step_tolerance: float, discretisation: tuple[float, tuple[float, ...]] | None, noisy: bool, state,
         position: int, block: np.ndarray) -> np.ndarray:
    """``data`` for the core: the buffer's ``slots`` (as above), the slave's largest clearance and sample clock, the
    filter's discretisation (step size, phi and gamma; None: none yet, and the core declines), whether there is noise,
    the slave's state (a :class:`~nfal.models.sensor_chain.SensorState`) and its noise block with the position in it
    (one longer than the core holds counts as used up: the slave draws until its next)."""
    step, transition = discretisation if discretisation is not None else (math.nan, (math.nan,) * 6)
    fits = block.size <= BLOCK
    head = [*slots, max_height, tolerance, start, period, step, step_tolerance, *transition, float(noisy),
            *state.filter_m, state.noise_m, state.measured_m, float(position), float(block.size if fits else 0)]
    data = np.zeros(len(head) + BLOCK)
    data[:len(head)] = head
    if fits:
        data[BLOCK_START:BLOCK_START + block.size] = block
    return data


@jit.kernel
def _at_sample(t, d):
    return clock_kernels.sample_index(t, d[_START], d[_PERIOD], d[_TOLERANCE]) >= 0


@jit.kernel
def advance(values, d, t, dt):
    """The step from ``t`` over ``dt`` on the buffer ``values``: 0 done, 1 left to the slave."""
    height = values[int(d[_SLOTS])]
    if not (math.isfinite(height) and height <= d[_MAX_HEIGHT]):
        return 1  # the slave refuses it, saying why
    if not (dt > 0.0 and math.isfinite(dt) and abs(d[_STEP] - dt) <= d[_STEP_TOLERANCE] * dt):
        return 1  # refused, or a step size the discretisation was not made for (or none yet)
    if not clock_kernels.divides(d[_PERIOD], dt, d[_TOLERANCE]):
        return 1  # a step that does not divide the sample period
    x = d[STATE:STATE + STATE_SIZE]
    y, rate, noise, measured, position, size = x[0], x[1], x[2], x[3], int(x[4]), int(x[5])
    if _at_sample(t, d):
        measured = y  # the filter's height, sampled (no quantiser: the slave's)
        noise = 0.0
        if d[_NOISY] != 0.0:
            if position >= size:
                return 1  # the block is used up: the slave draws the next
            noise = d[BLOCK_START + position]
            position += 1
    p = d[_PHI:_PHI + 6]
    y, rate = filter_step(y, rate, height + noise, p[0], p[1], p[2], p[3], p[4], p[5])
    x[0], x[1], x[2], x[3], x[4] = y, rate, noise, measured, position
    values[int(d[_SLOTS + 1])] = y if _at_sample(t + dt, d) else measured
    values[int(d[_SLOTS + 2])] = t + dt
    return 0


_STEP_FUNCTION = None


def _compile() -> None:
    global _STEP_FUNCTION
    import numba  # on use, as the kernels (models/jit.py)
    from numba import types

    buffer = types.CPointer(types.float64)

    @numba.cfunc(types.int32(buffer, types.intp, buffer, types.intp, types.float64, types.float64), cache=True)
    def step(values, n_values, data, n_data, t, dt):
        return advance(numba.carray(values, n_values), numba.carray(data, n_data), t, dt)

    _STEP_FUNCTION = step


def step_address() -> int:
    """The core's address (compiled, or loaded from numba's cache, on first use; the kernels with it)."""
    jit.load(_compile)
    return _STEP_FUNCTION.address
