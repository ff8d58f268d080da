"""A fast fixed-step stand-in for :meth:`SimplifiedPlant.advance` in free flight (same signature).

Classical RK4 on eq. (13) in SI over one zero-order-hold interval, with the number of sub-steps set by
the stiffest rate in play, the squeeze-film damping c(h) / m = 3 pi mu r0^4 / (2 m h^3): sub-steps of at
most ``STIFFNESS_STEP / (c / m)`` (RK4's stability limit is 2.79). Near the surface (below
``FALLBACK_FACTOR`` rest gaps), when resting, or when the sub-step count would exceed ``MAX_SUBSTEPS``,
it hands over to :meth:`SimplifiedPlant.advance`, which handles touchdown and lift-off.

About 10x faster than the adaptive LSODA path for the closed-loop runs of Figs. 9-10, and equal to it
within 1e-10 m per 0.5 ms step (|v| <= 5 mm/s, 40-200 um) and over a closed-loop run
(tests/test_closed_loop.py).
"""

from __future__ import annotations

import math

import numpy as np

from .calibration import PolynomialK
from .errors import InvalidParameterError, require_positive
from .plant import PlantState, SimplifiedPlant

#: Largest (damping rate x sub-step) taken.
STIFFNESS_STEP = 0.25
#: Below this many rest gaps the exact (event-handling) integrator takes over.
FALLBACK_FACTOR = 3.0
MAX_SUBSTEPS = 400
#: Fewest sub-steps, for RK4's truncation error: over 0.5 ms, 2 leave up to 2.3e-10 m, 4 leave 7e-11 m.
MIN_SUBSTEPS = 4


class FixedStepPlant:
    """:meth:`advance` like :class:`SimplifiedPlant`'s, by fixed-step RK4 away from the surface."""

    def __init__(self, plant: SimplifiedPlant) -> None:
        if not isinstance(plant, SimplifiedPlant):
            raise InvalidParameterError("plant", type(plant).__name__, "a SimplifiedPlant")
        rig = plant.rig
        self.plant = plant
        self._force_per_mass = rig.film_force_scale / rig.mass          # (a/h)^2 K -> m/s^2
        self._sigma_scale = float(rig.squeeze_number(1.0))              # sigma = this / h^2
        self._damping_per_mass = float(rig.squeeze_film_damping(1.0)) / rig.mass  # c(h)/m = this / h^3
        self._gravity = rig.gravity
        self._floor = FALLBACK_FACTOR * plant.rest_gap
        calibration = plant.calibration
        if isinstance(calibration, PolynomialK):
            coefficients = [float(c) for c in calibration.coefficients[::-1]]
            low, high = calibration.sigma_range

            def K(sigma: float) -> float:
                sigma = min(max(sigma, low), high)
                value = 0.0
                for c in coefficients:  # Horner
                    value = value * sigma + c
                return value
            self._K = K
        else:
            self._K = lambda sigma: float(calibration(sigma))

    def _acceleration(self, h: float, v: float, a: float) -> float:
        ratio = a / h
        return (self._force_per_mass * ratio * ratio * self._K(self._sigma_scale / (h * h))
                - self._damping_per_mass / (h * h * h) * v - self._gravity)

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
            return self.plant.advance(state, excitation, step)
        substeps = max(MIN_SUBSTEPS, math.ceil(step * self._damping_per_mass / lowest**3 / STIFFNESS_STEP))
        if substeps > MAX_SUBSTEPS:
            return self.plant.advance(state, excitation, step)
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
                return self.plant.advance(state, excitation, step)
        return PlantState(h, v, False)
