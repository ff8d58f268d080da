"""The sampled closed loop of Sec. 4.1 (Figs. 9-10) in plain Python: plant, noisy sensor, control law.

Every sample period T_s: the sensor reads the true clearance plus noise, the law of
:mod:`nfal.models.control_law` turns (reference, reading) into an excitation |a|, and
:meth:`SimplifiedPlant.advance` holds it for T_s (zero-order hold). The loop starts at the
equilibrium of the first reference level with a bumpless controller state.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from nfal.errors import InvalidParameterError

from .control_law import DiscreteControlLaw
from .plant import PlantState, SimplifiedPlant
from .reference import Staircase

logger = logging.getLogger(__name__)

INTEGRATORS = ("fixed_step", "adaptive")


@dataclasses.dataclass(frozen=True)
class ClosedLoopRun:
    """One simulated run sampled at the controller's instants (SI)."""

    controller: str
    time_s: np.ndarray
    reference_m: np.ndarray
    height_m: np.ndarray
    measured_m: np.ndarray
    excitation_m: np.ndarray


def simulate_closed_loop(law: DiscreteControlLaw, plant: SimplifiedPlant, reference: Staircase | None = None,
                         noise_m: np.ndarray | None = None, *, integrator: str = "fixed_step") -> ClosedLoopRun:
    """Run ``law`` against ``plant`` over the ``reference`` staircase.

    Parameters
    ----------
    law : DiscreteControlLaw
    plant : SimplifiedPlant
    reference : Staircase, optional
        Default: 60-100-140-180-140-100-60 um, 0.6 s per level.
    noise_m : ndarray, optional
        Measurement noise [m], one value per sample (at least as many as the run has); None: none.
    integrator : {"fixed_step", "adaptive"}
        Plant between samples: :class:`FixedStepPlant` (RK4, fast) or :meth:`SimplifiedPlant.advance`
        (LSODA with touchdown events, about 10x slower); they agree within 1e-10 m.
    """
    reference = reference or Staircase()
    if integrator not in INTEGRATORS:
        raise InvalidParameterError("integrator", integrator, f"one of {INTEGRATORS}")
    # imported here: its numba kernels take 0.65 s to load (``python -X importtime -c "import
    # nfal.models.fixed_step_plant"``), and what only reads a run (``nfal run``'s master: its FMUs carry their own)
    # never needs them
    from .fixed_step_plant import FixedStepPlant

    advance = FixedStepPlant(plant).advance if integrator == "fixed_step" else plant.advance
    samples = reference.samples(law.sample_rate_hz)
    if noise_m is None:
        noise_m = np.zeros(samples)
    noise_m = np.asarray(noise_m, dtype=float)
    if noise_m.ndim != 1 or noise_m.size < samples or not np.all(np.isfinite(noise_m)):
        raise InvalidParameterError("noise_m", f"{noise_m.size} values", f"{samples} finite values, one per sample")
    time = np.arange(samples) * law.period_s
    target = reference(time)
    start = float(target[0])
    state = PlantState(start)
    controller = law.initial_state(start, float(plant.equilibrium_excitation(start)))
    height, measured, excitation = np.empty(samples), np.empty(samples), np.empty(samples)
    for k in range(samples):
        height[k] = state.height
        measured[k] = state.height + noise_m[k]
        excitation[k], controller = law.step(controller, target[k], measured[k])
        state = advance(state, excitation[k], law.period_s)
    logger.info("%s: simulated %d samples", law.name, samples)
    return ClosedLoopRun(law.name, time, target, height, measured, excitation)
