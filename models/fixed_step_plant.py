"""A fast fixed-step stand-in for :meth:`SimplifiedPlant.advance` in free flight (same signature).

Classical RK4 on eq. (13) in SI over one zero-order-hold interval, with the number of sub-steps set by
the stiffest rate in play, the squeeze-film damping c(h) / m = 3 pi mu r0^4 / (2 m h^3): sub-steps of at
most ``slow_kernels.STIFFNESS_STEP / (c / m)`` (RK4's stability limit is 2.79). Near the surface (below
``FALLBACK_FACTOR`` rest gaps), when resting, or when the sub-step count would exceed ``slow_kernels.MAX_SUBSTEPS``,
it hands over to :meth:`SimplifiedPlant.advance`, which handles touchdown and lift-off. With the plant's
``excess_damping`` (Sec. 3.3) the damping and the stiffest rate are c(h) factor(h) / m, the rate taken
at the lower and the upper end of the step's reach (it may grow with h); without it nothing changes.

``near_surface="fast"`` replaces that hand-over (too slow for a real-time rig emulator: about 4 ms per
0.5 ms step at lift-off) by exponential Euler with the clearance frozen over sub-steps that move it by at
most ``slow_kernels.FAST_HEIGHT_FRACTION``: exact for the damping term at any stiffness, first order in the
clearance's change; touchdown is the first sub-step that reaches the rest gap. It follows the exact
path within 1 % of the clearance through a lift-off (tests/test_fixed_step_plant_fast.py).

The right-hand side, RK4 and the fast near-surface integrator are compiled (:mod:`nfal.models.slow_kernels`)
for every K (a calibration or a film table) and damping correction this package has; ``compiled=False`` leaves
them Python (models/jit.py: the same bits, a step about 30x slower) for a run too short to pay numba's load back.

About 10x faster than the adaptive LSODA path for the closed-loop runs of Figs. 9-10, and equal to it
within 1e-10 m per 0.5 ms step (|v| <= 5 mm/s, 40-200 um) and over a closed-loop run
(tests/test_closed_loop.py).
"""

from __future__ import annotations

import math

from nfal.errors import InvalidParameterError, require_amplitude, require_positive

from . import piecewise, slow_kernels
from .damping import DampingCorrection
from .plant import ExcessDamping, PlantState, SimplifiedPlant

#: Below this many rest gaps the exact (event-handling) integrator takes over.
FALLBACK_FACTOR = 3.0
#: ``near_surface`` choices: the exact event-handling integrator, or the fast exponential one.
NEAR_SURFACE = ("exact", "fast")


def damping_correction(model: ExcessDamping | DampingCorrection | None) -> tuple:
    """A plant's ``excess_damping`` as compiled code's damping correction (:mod:`nfal.models.slow_kernels`)."""
    if model is None:
        return slow_kernels.NO_CORRECTION, 1.0, 1.0, piecewise.NO_CURVE
    if isinstance(model, ExcessDamping):
        return slow_kernels.POWER_CORRECTION, float(model.height), float(model.exponent), piecewise.NO_CURVE
    return slow_kernels.CURVE_CORRECTION, 1.0, 1.0, model.log_factor_curve()


class FixedStepPlant:
    """:meth:`advance` like :class:`SimplifiedPlant`'s, by fixed-step RK4 away from the surface."""

    def __init__(self, plant: SimplifiedPlant, *, near_surface: str = "exact", compiled: bool = True) -> None:
        if not isinstance(plant, SimplifiedPlant):
            raise InvalidParameterError("plant", type(plant).__name__, "a SimplifiedPlant")
        if near_surface not in NEAR_SURFACE:
            raise InvalidParameterError("near_surface", near_surface, f"one of {NEAR_SURFACE}")
        self.near_surface = near_surface
        self._hand_over = plant.advance if near_surface == "exact" else self._exponential_advance
        rig = plant.rig
        self.plant = plant
        self._floor = FALLBACK_FACTOR * plant.rest_gap
        table = getattr(plant, "table", None)  # an AveragedFilmPlant: K(sigma, delta) of the full film
        K = table.curve() if table is not None else plant.calibration.curve()
        #: eq. (13) as compiled code's data (:mod:`nfal.models.slow_kernels`)
        self.model = (float(rig.film_force_scale / rig.mass), float(rig.squeeze_number(1.0)),
                      float(rig.squeeze_film_damping(1.0)) / rig.mass, float(rig.gravity), K,
                      damping_correction(plant.excess_damping))
        if compiled:  # else the kernels run as Python until someone compiles them: a short run's choice
            slow_kernels.load()

    @property
    def floor(self) -> float:
        """The clearance [m] below which the exact (or fast) near-surface integrator takes over."""
        return self._floor

    def acceleration(self, h: float, v: float, a: float) -> float:
        """Eq. (13) in SI [m/s^2], as the integrators evaluate it."""
        return slow_kernels.acceleration(self.model, h, v, a)

    def _exponential_advance(self, state: PlantState, excitation: float, step: float) -> PlantState:
        """Near the surface, fast: see the module docstring (``near_surface="fast"``)."""
        rest = self.plant.rest_gap
        if state.resting or (state.height <= rest and state.velocity <= 0):
            h, v = rest, 0.0  # lifts off from the rest gap (the caller has checked that it does not rest)
        else:
            h, v = float(state.height), float(state.velocity)
        h, v, landed = slow_kernels.exponential_advance(self.model, h, v, float(excitation), step, rest)
        return PlantState(h, v, landed)

    def advance(self, state: PlantState, excitation: float, step: float) -> PlantState:
        """The state ``step`` seconds later under a constant |a| = ``excitation`` [m] (zero-order hold)."""
        step = require_positive("step", step)
        excitation = require_amplitude("excitation", excitation)
        h, v = float(state.height), float(state.velocity)
        if not (math.isfinite(h) and math.isfinite(v)):
            raise InvalidParameterError("state", state, "a finite height and velocity")
        if not state.resting:
            h, v, outcome = slow_kernels.free_flight_step(self.model, h, v, float(excitation), step, self._floor)
            if outcome == slow_kernels.FLEW:
                return PlantState(h, v, False)
            if outcome == slow_kernels.HANDED_OVER:  # too stiff, or it left free flight (near the surface, not finite)
                return self._hand_over(state, excitation, step)
        if self.plant.rests(state, excitation):  # held on the surface the whole step: nothing to integrate
            return PlantState(self.plant.rest_gap, 0.0, True)
        return self._hand_over(state, excitation, step)
