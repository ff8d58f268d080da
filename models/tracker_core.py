"""The ResonanceTracker's step as a C function: what the FMU runtime's value cache calls for its doStep without entering
Python (fmus/value_cache/, docs/cosimulation.md, "the value cache"), with the transducer's dynamics on (its outputs
are then its state's).

:func:`step_address` is a numba ``cfunc`` with :mod:`~nfal.models.plant_core`'s signature. ``values`` is the runtime's
buffer; ``data`` is :func:`pack`'s array: the buffer's slots, the checks the slave makes, the sample clock, the
transducer, the PLL's constants and the state (envelope, PLL), which the core keeps. It does what
:meth:`ResonanceTracker.advance <nfal.models.pll.ResonanceTracker.advance>` and the outputs' read after it do, with the
same kernels (:mod:`~nfal.models.tracker_kernels`), and answers 0; an input or a step size the slave refuses, a
state that is not finite or a drive frequency the transducer refuses (a state restored with one), it leaves untouched
and answers 1: the slave's Python steps, and says why if it fails.
"""

from __future__ import annotations

import math

import numpy as np

from . import clock_kernels, jit, tracker_kernels

#: The files whose kernels the compiled core holds (part of its numba cache key, models/numba_cache.py).
KERNEL_DEPENDENCIES = ("tracker_kernels.py", "clock_kernels.py")
#: ``data``: the buffer's slots (drive voltage, resonance shift, excitation amplitude, drive frequency, locked, phase
#: error, the time the core stepped to), the largest drive voltage, the sample clock's tolerance, start and period,
#: the transducer (resonance, Q, metres per volt), the PLL's constants (``PhaseLockedLoop.constants``), the state.
_SLOTS, _MAX_VOLTAGE, _TOLERANCE, _START, _PERIOD, _TRANSDUCER, _PLL = 0, 7, 8, 9, 10, 11, 14
STATE = _PLL + 9
STATE_SIZE = 7


def state_values(state) -> list[float]:
    """A :class:`~nfal.models.pll.TrackerState` as the core keeps it: envelope (real, imaginary), frequency,
    integrator, phase error, lock count, locked."""
    pll = state.pll
    return [state.envelope_m.real, state.envelope_m.imag, pll.drive_frequency_hz, pll.integrator_hz,
            pll.phase_error_rad, float(pll.lock_count), float(pll.locked)]


def pack(slots: tuple[int, ...], tracker, max_voltage: float, tolerance: float, start: float, state) -> np.ndarray:
    """``data`` for the core: the buffer's ``slots`` (as above), the slave's largest drive voltage, its sample clock
    (``tolerance``, ``start``; the PLL's period) and ``tracker`` (a :class:`~nfal.models.pll.ResonanceTracker`) in
    ``state``."""
    transducer, pll = tracker.transducer, tracker.pll
    head = [*slots, max_voltage, tolerance, start, pll.period_s, transducer.resonance_frequency_hz,
            transducer.quality_factor, transducer.metres_per_volt, *(float(c) for c in pll.constants)]
    return np.array([*head, *state_values(state)], dtype=float)


@jit.kernel
def _sample(d, re, im, frequency, integrator, error, count, locked):
    p = d[_PLL:_PLL + 9]
    return tracker_kernels.pll_sample(re, im, frequency, integrator, count, locked, p[0], p[1], p[2], p[3], p[4],
                                      p[5], int(p[6]), p[7], p[8] != 0.0)


@jit.kernel
def _at_sample(t, d):
    return clock_kernels.sample_index(t, d[_START], d[_PERIOD], d[_TOLERANCE]) >= 0


@jit.kernel
def advance(values, d, t, dt):
    """The step from ``t`` over ``dt`` on the buffer ``values``: 0 done, 1 left to the slave."""
    s = d[_SLOTS:_SLOTS + 7]
    voltage, shift = values[int(s[0])], values[int(s[1])]
    resonance = d[_TRANSDUCER]
    if not (voltage >= 0.0 and voltage <= d[_MAX_VOLTAGE] and abs(shift) < 0.5 * resonance):
        return 1  # the slave refuses it, saying why (NaN fails every comparison)
    if not (dt > 0.0 and math.isfinite(dt)):
        return 1
    if not clock_kernels.divides(d[_PERIOD], dt, d[_TOLERANCE]):
        return 1  # a step that does not divide the PLL's period
    x = d[STATE:STATE + STATE_SIZE]
    re, im, frequency, integrator, error, count, locked = x[0], x[1], x[2], x[3], x[4], int(x[5]), x[6] != 0.0
    if not (math.isfinite(re) and math.isfinite(im)):
        return 1
    if _at_sample(t, d):
        frequency, integrator, error, count, locked = _sample(d, re, im, frequency, integrator, error, count, locked)
    if not (frequency > 0.0 and math.isfinite(frequency)):
        return 1  # a drive frequency the transducer refuses (a state restored with one)
    re, im = tracker_kernels.envelope_step(re, im, voltage, frequency, resonance + shift, d[_TRANSDUCER + 1],
                                           d[_TRANSDUCER + 2], dt)
    x[0], x[1], x[2], x[3], x[4], x[5], x[6] = re, im, frequency, integrator, error, count, 1.0 if locked else 0.0
    if _at_sample(t + dt, d):  # the outputs read at t + dt: that sample, not committed (the next step takes it)
        frequency, integrator, error, count, locked = _sample(d, re, im, frequency, integrator, error, count, locked)
    values[int(s[2])] = abs(complex(re, im))
    values[int(s[3])], values[int(s[4])], values[int(s[5])] = frequency, 1.0 if locked else 0.0, error
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
    """The core's address (compiled, or loaded from numba's cache, on first use; the kernels with it)."""
    jit.load(_compile)
    return _STEP.address
