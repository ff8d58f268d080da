"""Compiled kernels of eq. (13)'s fixed-step integration (numba), for
:class:`~nfal.models.fixed_step_plant.FixedStepPlant`.

Every K this package has is one piecewise polynomial, a *curve* ``(log_axis, breaks, pieces, low, high,
delta_max)``: the argument x is clamped to [low, high] (and taken as log x when ``log_axis``), and in the
interval i of ``breaks`` that holds it

    K = sum_p delta^(2p) poly(pieces[i, p], x - breaks[i])     (each poly's coefficients highest power first,
                                                                 |delta| held at delta_max)

A :class:`~nfal.models.calibration.PolynomialK` is one piece in sigma, a
:class:`~nfal.models.calibration.TabulatedK` cubic pieces in log sigma, a
:class:`~nfal.models.film_force_table.FilmForceTable` cubic pieces in log sigma per power of delta^2. A damping
correction is ``(kind, height, exponent, curve)``: kind 0 none, 1 the factor 1 + (h / height)^exponent of
:class:`~nfal.models.plant.ExcessDamping`, 2 exp(curve(h)) of a
:class:`~nfal.models.damping.DampingCorrection`. A *model* is ``(film force per mass over delta^2 K, sigma h^2,
c(h) h^3 / m, g, K curve, damping correction)``.

In plain Python the slow truth's RK4 cost the rig emulator ~105 us of its 500 us tick (bench/bench_rig_truth.py).

Every curve and model has the same numba types (float64 C arrays, floats, an int kind: curves are made by
:func:`nfal.models.piecewise.curve`), so one compiled specialisation serves all; :func:`load` compiles and loads it
(models/jit.py: until then the kernels run as Python, bit for bit the same).
"""

from __future__ import annotations

import math

import numpy as np

from . import jit, piecewise
from .jit import kernel

#: Largest (damping rate x sub-step) taken (RK4's stability limit is 2.79).
STIFFNESS_STEP = 0.25
#: Largest relative change of the clearance in one sub-step of the fast near-surface integrator.
FAST_HEIGHT_FRACTION = 0.005
#: Most sub-steps of the fast near-surface integrator per step.
FAST_MAX_SUBSTEPS = 2000
#: Damping correction kinds.
NO_CORRECTION, POWER_CORRECTION, CURVE_CORRECTION = 0, 1, 2
#: Fewest RK4 sub-steps of a step, for RK4's truncation error: over 0.5 ms, 2 leave up to 2.3e-10 m, 4 leave 7e-11 m.
MIN_SUBSTEPS = 4
#: More sub-steps than this: the step is left to the exact integrator.
MAX_SUBSTEPS = 400
#: :func:`free_flight_step`'s outcomes: stepped; starting below the floor (resting, or the exact integrator's); left to
#: the exact integrator (too stiff a step, or the object left free flight).
FLEW, BELOW_FLOOR, HANDED_OVER = 0, 1, 2


@kernel
def curve_value(log_axis, breaks, pieces, low, high, delta_max, x, delta):
    """The curve (module docstring) at ``x`` and ``delta``."""
    x = min(max(x, low), high)
    if log_axis:
        x = math.log(x)
    interval = min(max(np.searchsorted(breaks, x, side="right") - 1, 0), breaks.shape[0] - 2)
    t = x - breaks[interval]
    reach = min(abs(delta), delta_max)
    squared = reach * reach  # not ** 2: CPython's pow() and numba's x * x differ in the last bit now and then
    value = 0.0
    for power in range(pieces.shape[1] - 1, -1, -1):  # Horner in delta^2 over polynomials in t
        piece = 0.0
        for c in pieces[interval, power]:
            piece = piece * t + c
        value = value * squared + piece
    return value


@kernel
def damping_factor(correction, h):
    """The damping correction's factor on eq. (6) at the clearance ``h``."""
    kind, height, exponent, curve = correction
    if kind == POWER_CORRECTION:
        return 1.0 + (h / height) ** exponent
    if kind == CURVE_CORRECTION:
        return math.exp(curve_value(*curve, h, 0.0))
    return 1.0


@kernel
def damping_rate(model, h):
    """c(h) f(h) / m [1/s]."""
    return model[2] / (h * h * h) * damping_factor(model[5], h)


@kernel
def drift(model, h, a):
    """The acceleration [m/s^2] at rest: film force / m - g."""
    ratio = a / h
    return model[0] * ratio * ratio * curve_value(*model[4], model[1] / (h * h), ratio) - model[3]


@kernel
def acceleration(model, h, v, a):
    """Eq. (13) in SI: (film force - c(h) f(h) v) / m - g."""
    return drift(model, h, a) - damping_rate(model, h) * v


@kernel
def substeps(model, step, lowest, highest):
    """RK4 sub-steps for ``step`` s over clearances [lowest, highest]: the damping rate's largest value there
    is at one end (for ExcessDamping, h^-3 + h^(n-3) / H^n falls and then rises; a table's PCHIP pieces vary
    little over one step's reach, and RK4's limit is 11x STIFFNESS_STEP)."""
    rate = max(damping_rate(model, lowest), damping_rate(model, highest))
    return math.ceil(step * rate / STIFFNESS_STEP)


@kernel
def free_flight(model, h, v, a, step, count, floor):
    """Classical RK4 over ``step`` s in ``count`` sub-steps: (h, v, stayed above ``floor`` and finite)."""
    dt = step / count
    for _ in range(count):
        k1h, k1v = v, acceleration(model, h, v, a)
        k2h, k2v = v + 0.5 * dt * k1v, acceleration(model, h + 0.5 * dt * k1h, v + 0.5 * dt * k1v, a)
        k3h, k3v = v + 0.5 * dt * k2v, acceleration(model, h + 0.5 * dt * k2h, v + 0.5 * dt * k2v, a)
        k4h, k4v = v + dt * k3v, acceleration(model, h + dt * k3h, v + dt * k3v, a)
        h += dt / 6.0 * (k1h + 2.0 * k2h + 2.0 * k3h + k4h)
        v += dt / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
        if not (h > floor and np.isfinite(v)):
            return h, v, False
    return h, v, True


@kernel
def free_flight_step(model, h, v, a, step, floor):
    """One step of free flight above ``floor``, in as many RK4 sub-steps as the stiffest damping rate in the step's
    reach asks (:class:`~nfal.models.fixed_step_plant.FixedStepPlant`): (h, v, outcome); unchanged unless FLEW."""
    lowest = h - max(-v, 0.0) * step
    if lowest < floor:
        return h, v, BELOW_FLOOR
    count = max(MIN_SUBSTEPS, substeps(model, step, lowest, h + max(v, 0.0) * step))
    if count > MAX_SUBSTEPS:
        return h, v, HANDED_OVER
    flown_h, flown_v, stayed = free_flight(model, h, v, a, step, count, floor)
    if not stayed:
        return h, v, HANDED_OVER
    return flown_h, flown_v, FLEW


@kernel
def oscillation(sigma_scale, log_sigmas, response, h, a):
    """Amplitude [m] of the object's fast oscillation at clearance ``h`` with |a| = ``a`` (eq. 1, to first order in
    delta): |a| |zeta / delta|, |zeta / delta| interpolated linearly in log sigma, sigma = ``sigma_scale`` / h^2,
    between the table's points (``AveragedFilmPlant.oscillation_table``)."""
    return np.interp(math.log(sigma_scale / (h * h)), log_sigmas, response) * a


@kernel
def exponential_advance(model, h, v, a, step, rest):
    """Exponential Euler over ``step`` s with the clearance frozen over sub-steps that move it by at most
    FAST_HEIGHT_FRACTION: exact for the damping term at any stiffness. Returns (h, v, landed): landed when
    a sub-step reaches the ``rest`` gap."""
    shortest = step / FAST_MAX_SUBSTEPS
    elapsed = 0.0
    while elapsed < step:
        rate = damping_rate(model, h)
        dt = min(step - elapsed, max(shortest, FAST_HEIGHT_FRACTION * h / max(abs(v), 1e-12)))
        decay = math.exp(-rate * dt)
        terminal = drift(model, h, a) / rate  # the velocity at which damping balances the other forces
        h += terminal * dt + (v - terminal) * (1.0 - decay) / rate
        v = terminal + (v - terminal) * decay
        elapsed += dt
        if h <= rest:
            return rest, 0.0, True
    return h, v, False


#: A model of the types every model has (the module's docstring): what :func:`load` loads the kernels for.
ANY_MODEL = (1.0, 1.0, 1.0, 9.81, piecewise.NO_CURVE, (NO_CORRECTION, 1.0, 1.0, piecewise.NO_CURVE))


def _call_every_kernel() -> None:
    h = 100e-6
    free_flight(ANY_MODEL, h, 0.0, 0.0, 1e-6, 1, 0.0)
    free_flight_step(ANY_MODEL, h, 0.0, 0.0, 1e-6, 0.0)
    exponential_advance(ANY_MODEL, h, 0.0, 0.0, 1e-9, 0.0)
    substeps(ANY_MODEL, 1e-6, h, h)
    acceleration(ANY_MODEL, h, 0.0, 0.0)
    curve_value(*ANY_MODEL[4], 1.0, 0.0)
    oscillation(1.0, np.array([0.0, 1.0]), np.array([0.0, 1.0]), 1.0, 0.0)


def load() -> None:
    """Compile the kernels and load them (every model has the same types): before a real-time loop, or a run long
    enough to pay that back (models/jit.py). A call after the first returns at once."""
    jit.load(_call_every_kernel)
