"""The harmonic-balance plant's free-flight step as a C function: what the FMU runtime's value cache calls for a
ReynoldsPlant's doStep without entering Python (fmus/value_cache/, docs/cosimulation.md, "the value cache").

:func:`step_address` is a numba ``cfunc`` (its signature there). ``values``
is the runtime's buffer (the slave's inputs and outputs, and the time); ``data`` is
:func:`pack`'s array: the slots it reads and writes, eq. (13)'s model of :class:`~nfal.models.fixed_step_plant.
FixedStepPlant` (the same kernels, :mod:`nfal.models.slow_kernels`, so the same bits), the clearance below which the
exact integrator takes over, the contact's reach and the oscillation's table. It does what
:meth:`~nfal.models.film_backends.HarmonicBalanceFilm.advance` does in free flight and answers 0; anything else (an
input the slave would refuse, a new drive frequency, touchdown, resting, near the surface, too stiff a step, leaving
free flight) it leaves untouched and answers 1, and the runtime calls the slave's Python ``do_step``, which does it
all and says why if it fails.
"""

from __future__ import annotations

import math

import numpy as np

from . import jit, slow_kernels
from .fixed_step_plant import FixedStepPlant
from .plausibility import MAX_EXCITATION_M
from .rig import FREQUENCY_TOLERANCE

#: The files whose kernels and constants the compiled core holds (part of its numba cache key, models/numba_cache.py).
KERNEL_DEPENDENCIES = ("slow_kernels.py", "plausibility.py", "rig.py")
#: ``data``: slots of the buffer (excitation, drive frequency, height, velocity, resting, oscillation, the time the
#: core stepped to: fmus/base.py's CORE_TIME), then the
#: frequency the model is built for, the floor, the contact's reach per metre of |a|, sigma h^2 over the oscillation
#: table, the model's four numbers; then the K curve, the damping correction and the oscillation table (each with
#: its sizes first).
_SLOTS, _FREQUENCY, _FLOOR, _REACH, _SIGMA_SCALE, _MODEL = 0, 7, 8, 9, 10, 11
_CURVE = _MODEL + 4


def _curve_data(curve) -> list[np.ndarray]:
    log_axis, breaks, pieces, low, high, delta_max = curve
    return [np.array([float(log_axis), low, high, delta_max, breaks.size, *pieces.shape]), breaks, pieces.ravel()]


def pack(slots: tuple[int, ...], stepper: FixedStepPlant, reach: float) -> np.ndarray:
    """``data`` for the core: the buffer's ``slots`` (as above), ``stepper``'s model and floor, and ``reach``, the
    surface's largest excursion per metre of |a| (touchdown)."""
    model, plant = stepper.model, stepper.plant
    kind, height, exponent, correction = model[5]
    sigma_scale, log_sigmas, response = plant.oscillation_table()
    head = [*slots, plant.rig.frequency, stepper.floor, reach, sigma_scale, *model[:4]]
    parts = [np.array(head, dtype=float), *_curve_data(model[4]), np.array([kind, height, exponent], dtype=float),
             *_curve_data(correction), np.array([log_sigmas.size], dtype=float), log_sigmas, response]
    return np.ascontiguousarray(np.concatenate([np.asarray(p, dtype=float) for p in parts]))


@jit.kernel
def _curve(d, o):
    """The curve at ``d[o:]`` and the offset after it."""
    nb, ni, npw, nc = int(d[o + 4]), int(d[o + 5]), int(d[o + 6]), int(d[o + 7])
    breaks = d[o + 8:o + 8 + nb]
    start = o + 8 + nb
    pieces = d[start:start + ni * npw * nc].reshape((ni, npw, nc))
    return (d[o] != 0.0, breaks, pieces, d[o + 1], d[o + 2], d[o + 3]), start + ni * npw * nc


@jit.kernel
def advance(values, d, t, dt):
    """The step from ``t`` over ``dt`` on the buffer ``values``: 0 done, 1 left to the slave."""
    s = d[_SLOTS:_SLOTS + 7]
    a, f = values[int(s[0])], values[int(s[1])]
    h, v = values[int(s[2])], values[int(s[3])]
    if not (a >= 0.0 and a <= MAX_EXCITATION_M and f > 0.0 and math.isfinite(f) and dt > 0.0 and math.isfinite(dt)):
        return 1  # the slave refuses it, saying why
    if abs(f - d[_FREQUENCY]) > FREQUENCY_TOLERANCE * d[_FREQUENCY] or values[int(s[4])] != 0.0:
        return 1  # a new drive frequency (the slave rebuilds its model), or resting
    if a * d[_REACH] >= h or not (math.isfinite(h) and math.isfinite(v)):
        return 1  # touchdown
    curve, o = _curve(d, _CURVE)
    kind, height, exponent = int(d[o]), d[o + 1], d[o + 2]
    correction_curve, o = _curve(d, o + 3)
    model = (d[_MODEL], d[_MODEL + 1], d[_MODEL + 2], d[_MODEL + 3], curve, (kind, height, exponent, correction_curve))
    h, v, outcome = slow_kernels.free_flight_step(model, h, v, a, dt, d[_FLOOR])
    if outcome != slow_kernels.FLEW:
        return 1  # near the surface, too stiff a step, or it left free flight: the slave's integrators
    n = int(d[o])
    values[int(s[2])], values[int(s[3])] = h, v
    values[int(s[5])] = slow_kernels.oscillation(d[_SIGMA_SCALE], d[o + 1:o + 1 + n], d[o + 1 + n:o + 1 + 2 * n], h, a)
    values[int(s[6])] = t + dt
    return 0


_STEP = None


def _compile() -> None:
    global _STEP
    import numba  # on use, as the kernels (models/jit.py)
    from numba import types

    buffer = types.CPointer(types.float64)

    @numba.cfunc(types.int32(buffer, types.intp, buffer, types.intp, types.float64, types.float64), cache=True)
    def step(values, n_values, data, n_data, t, dt):
        return advance(numba.carray(values, n_values), numba.carray(data, n_data), t, dt)

    _STEP = step


def step_address() -> int:
    """The core's address: ``int step(double* values, size_t n_values, double* data, size_t n_data, double t,
    double dt)`` (compiled, or loaded from numba's cache, on first use; the kernels with it)."""
    slow_kernels.load()
    jit.load(_compile)
    return _STEP.address
