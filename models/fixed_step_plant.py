"""A fast fixed-step stand-in for :meth:`SimplifiedPlant.advance` in free flight (same signature).

Classical RK4 on eq. (13) in SI over one zero-order-hold interval, with the number of sub-steps set by
the stiffest rate in play, the squeeze-film damping c(h) / m = 3 pi mu r0^4 / (2 m h^3): sub-steps of at
most ``STIFFNESS_STEP / (c / m)`` (RK4's stability limit is 2.79). Near the surface (below
``FALLBACK_FACTOR`` rest gaps), when resting, or when the sub-step count would exceed ``MAX_SUBSTEPS``,
it hands over to :meth:`SimplifiedPlant.advance`, which handles touchdown and lift-off. With the plant's
``excess_damping`` (Sec. 3.3) the damping and the stiffest rate are c(h) factor(h) / m, the rate taken
at the lower and the upper end of the step's reach (it may grow with h); without it nothing changes.

``near_surface="fast"`` replaces that hand-over (too slow for a real-time rig emulator: about 4 ms per
0.5 ms step at lift-off) by exponential Euler with the clearance frozen over sub-steps that move it by at
most ``FAST_HEIGHT_FRACTION``: exact for the damping term at any stiffness, first order in the
clearance's change; touchdown is the first sub-step that reaches the rest gap. It follows the exact
path within 1 % of the clearance through a lift-off (tests/test_fixed_step_plant_fast.py).

About 10x faster than the adaptive LSODA path for the closed-loop runs of Figs. 9-10, and equal to it
within 1e-10 m per 0.5 ms step (|v| <= 5 mm/s, 40-200 um) and over a closed-loop run
(tests/test_closed_loop.py).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from nfal.errors import InvalidParameterError, require_positive

from .plant import PlantState, SimplifiedPlant

#: Largest (damping rate x sub-step) taken.
STIFFNESS_STEP = 0.25
#: Below this many rest gaps the exact (event-handling) integrator takes over.
FALLBACK_FACTOR = 3.0
MAX_SUBSTEPS = 400
#: Fewest sub-steps, for RK4's truncation error: over 0.5 ms, 2 leave up to 2.3e-10 m, 4 leave 7e-11 m.
MIN_SUBSTEPS = 4
#: ``near_surface`` choices: the exact event-handling integrator, or the fast exponential one.
NEAR_SURFACE = ("exact", "fast")
#: Largest relative change of the clearance in one sub-step of the fast near-surface integrator.
FAST_HEIGHT_FRACTION = 0.005
#: Most sub-steps of the fast near-surface integrator per step.
FAST_MAX_SUBSTEPS = 2000


class FixedStepPlant:
    """:meth:`advance` like :class:`SimplifiedPlant`'s, by fixed-step RK4 away from the surface."""

    def __init__(self, plant: SimplifiedPlant, *, near_surface: str = "exact") -> None:
        if not isinstance(plant, SimplifiedPlant):
            raise InvalidParameterError("plant", type(plant).__name__, "a SimplifiedPlant")
        if near_surface not in NEAR_SURFACE:
            raise InvalidParameterError("near_surface", near_surface, f"one of {NEAR_SURFACE}")
        self.near_surface = near_surface
        self._hand_over = plant.advance if near_surface == "exact" else self._exponential_advance
        rig = plant.rig
        self.plant = plant
        self._force_per_mass = rig.film_force_scale / rig.mass          # (a/h)^2 K -> m/s^2
        self._sigma_scale = float(rig.squeeze_number(1.0))              # sigma = this / h^2
        self._damping_per_mass = float(rig.squeeze_film_damping(1.0)) / rig.mass  # c(h)/m = this / h^3
        self._gravity = rig.gravity
        self._floor = FALLBACK_FACTOR * plant.rest_gap
        self._free_flight = self._rk4
        table = getattr(plant, "table", None)  # an AveragedFilmPlant: K(sigma, delta) of the full film
        if table is not None:
            self._K = table.scalar
            if plant.excess_damping is None:  # the same RK4, compiled
                self._free_flight = functools.partial(plant.free_flight, floor=self._floor)
        else:
            scalar = plant.calibration.scalar
            self._K = lambda sigma, delta: scalar(sigma)
        excess = plant.excess_damping
        if excess is not None:  # chosen here, so that the plain path stays as fast as without the option
            self._factor = excess.factor_scalar
            self._acceleration = self._corrected_acceleration
            self._substeps = self._corrected_substeps

    def _acceleration(self, h: float, v: float, a: float) -> float:
        ratio = a / h
        return (self._force_per_mass * ratio * ratio * self._K(self._sigma_scale / (h * h), ratio)
                - self._damping_per_mass / (h * h * h) * v - self._gravity)

    def _corrected_acceleration(self, h: float, v: float, a: float) -> float:
        ratio = a / h
        factor = self._factor(h)
        return (self._force_per_mass * ratio * ratio * self._K(self._sigma_scale / (h * h), ratio)
                - self._damping_per_mass / (h * h * h) * factor * v - self._gravity)

    def _damping_rate(self, h: float) -> float:
        """c(h) / m [1/s], with the excess factor if the plant has one."""
        rate = self._damping_per_mass / (h * h * h)
        excess = self.plant.excess_damping
        return rate if excess is None else rate * excess.factor_scalar(h)

    def _exponential_advance(self, state: PlantState, excitation: float, step: float) -> PlantState:
        """Near the surface, fast: see the module docstring (``near_surface="fast"``)."""
        plant = self.plant
        rest = plant.rest_gap
        if state.resting or (state.height <= rest and state.velocity <= 0):
            h, v = rest, 0.0  # lifts off from the rest gap (the caller has checked that it does not rest)
        else:
            h, v = float(state.height), float(state.velocity)
        shortest = step / FAST_MAX_SUBSTEPS
        elapsed = 0.0
        while elapsed < step:
            rate = self._damping_rate(h)
            ratio = excitation / h
            drift = self._force_per_mass * ratio * ratio * self._K(self._sigma_scale / (h * h), ratio) - self._gravity
            dt = min(step - elapsed, max(shortest, FAST_HEIGHT_FRACTION * h / max(abs(v), 1e-12)))
            decay = math.exp(-rate * dt)
            terminal = drift / rate  # the velocity at which damping balances the other forces
            h += terminal * dt + (v - terminal) * (1.0 - decay) / rate
            v = terminal + (v - terminal) * decay
            elapsed += dt
            if h <= rest:
                return PlantState(rest, 0.0, True)
        return PlantState(h, v, False)

    def _substeps(self, step: float, lowest: float, highest: float) -> int:
        return math.ceil(step * self._damping_per_mass / lowest**3 / STIFFNESS_STEP)

    def _corrected_substeps(self, step: float, lowest: float, highest: float) -> int:
        # c(h) f(h) / m: for ExcessDamping, k (h^-3 + h^(n-3) / H^n) falls and then rises with h, so its largest
        # value over [lowest, highest] is at one end; a table's PCHIP pieces vary little over one step's reach
        # (RK4's limit is 11x STIFFNESS_STEP)
        rate = max(self._damping_per_mass / h**3 * self._factor(h) for h in (lowest, highest))
        return math.ceil(step * rate / STIFFNESS_STEP)

    def advance(self, state: PlantState, excitation: float, step: float) -> PlantState:
        """The state ``step`` seconds later under a constant |a| = ``excitation`` [m] (zero-order hold)."""
        step = require_positive("step", step)
        if not (math.isfinite(excitation) and excitation >= 0):
            raise InvalidParameterError("excitation", excitation, "a finite amplitude >= 0 m")
        h, v = float(state.height), float(state.velocity)
        if not (math.isfinite(h) and math.isfinite(v)):
            raise InvalidParameterError("state", state, "a finite height and velocity")
        lowest = h - max(-v, 0.0) * step
        if state.resting or lowest < self._floor:
            if self.plant.rests(state, excitation):  # held on the surface the whole step: nothing to integrate
                return PlantState(self.plant.rest_gap, 0.0, True)
            return self._hand_over(state, excitation, step)
        substeps = max(MIN_SUBSTEPS, self._substeps(step, lowest, h + max(v, 0.0) * step))
        if substeps > MAX_SUBSTEPS:
            return self._hand_over(state, excitation, step)
        moved = self._free_flight(h, v, excitation, step, substeps)
        if moved is None:  # left free flight (near the surface, or not finite)
            return self._hand_over(state, excitation, step)
        return PlantState(moved[0], moved[1], False)

    def _rk4(self, h: float, v: float, excitation: float, step: float, substeps: int) -> tuple[float, float] | None:
        """RK4 over ``step`` in ``substeps``: (h, v), or None when the height falls to the floor."""
        dt = step / substeps
        f = self._acceleration
        for _ in range(substeps):
            k1h, k1v = v, f(h, v, excitation)
            k2h, k2v = v + 0.5 * dt * k1v, f(h + 0.5 * dt * k1h, v + 0.5 * dt * k1v, excitation)
            k3h, k3v = v + 0.5 * dt * k2v, f(h + 0.5 * dt * k2h, v + 0.5 * dt * k2v, excitation)
            k4h, k4v = v + dt * k3v, f(h + dt * k3h, v + dt * k3v, excitation)
            h += dt / 6.0 * (k1h + 2.0 * k2h + 2.0 * k3h + k4h)
            v += dt / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
            if not (h > self._floor and np.isfinite(v)):
                return None
        return h, v
