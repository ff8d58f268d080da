"""Figs. 9-10: the gain-scheduled controller and linear designs, each closing the 2 kHz loop around the simplified
plant over the same reference and the same measurement noise."""

from __future__ import annotations

from collections.abc import Callable, Sequence

from .calibration import CalibrationFunction
from .closed_loop import ClosedLoopRun, simulate_closed_loop
from .reference import Staircase
from .control_law import DiscreteControlLaw
from .measurement_noise import coloured_noise
from .pid_design import DesignSpec, GainSchedule, design_schedule, fixed_design
from .plant import DampingModel, SimplifiedPlant
from .rig import RigParameters
from .stability import realizable_schedule

#: The controller key of the gain-scheduled design; any other key is a linear design's height in um.
GAIN_SCHEDULED = "gs"


def controller_name(key: str) -> str:
    """How a controller key reads: ``"gain-scheduled"`` or ``"linear at 80 um"`` (the gains' own names)."""
    return "gain-scheduled" if key == GAIN_SCHEDULED else f"linear at {float(key):g} um"


def controller_design(key: str) -> dict:
    """The Controller FMU's design parameters of controller ``key`` (the same design, in co-simulation)."""
    if key == GAIN_SCHEDULED:
        return {"Controller.design": "gain-scheduled"}
    return {"Controller.design": "fixed", "Controller.design_height": float(key) * 1e-6}


def controller_gains(key: str, rig: RigParameters, calibration: CalibrationFunction, spec: DesignSpec, *,
                     sample_rate_hz: float, damping: DampingModel | None = None,
                     full_schedule: bool = False) -> GainSchedule:
    """The gains of controller ``key``: ``"gs"`` the schedule over the work range (with the continuous placement
    held from the lowest height its 2 kHz loop realises, unless ``full_schedule``), else one fixed design at
    ``float(key)`` um (eqs. 23-24 at one point)."""
    if key != GAIN_SCHEDULED:
        return fixed_design(float(key) * 1e-6, rig, calibration, spec, damping=damping)
    gains = design_schedule(None, rig, calibration, spec, damping=damping)
    if full_schedule:
        return gains
    return realizable_schedule(gains, rig, sample_rate_hz=sample_rate_hz,
                               discretisation="zoh" if spec.sample_rate_hz else "forward_euler")


def simulate_comparison(keys: Sequence[str], rig: RigParameters, calibration: CalibrationFunction, spec: DesignSpec,
                        reference: Staircase, *, sample_rate_hz: float, max_excitation_m: float, noise_peak_m: float,
                        noise_cutoff_hz: float, seed: int, damping: DampingModel | None = None,
                        full_schedule: bool = False,
                        progress: Callable[[], None] | None = None) -> dict[str, ClosedLoopRun]:
    """Each controller of ``keys`` (:func:`controller_gains`) against the simplified plant (eq. 13, with the
    ``damping`` correction), the same coloured noise for all (Sec. 4.2): key -> run. ``progress`` is called after
    each run."""
    plant = SimplifiedPlant(rig, calibration, excess_damping=damping)
    noise = coloured_noise(reference.samples(sample_rate_hz), sample_rate_hz=sample_rate_hz, cutoff_hz=noise_cutoff_hz,
                           peak_m=noise_peak_m, seed=seed)
    work_range = (min(reference.levels_m), max(reference.levels_m))
    runs = {}
    for key in keys:
        gains = controller_gains(key, rig, calibration, spec, sample_rate_hz=sample_rate_hz, damping=damping,
                                 full_schedule=full_schedule)
        law = DiscreteControlLaw(gains, sample_rate_hz=sample_rate_hz, max_excitation_m=max_excitation_m,
                                 reference_range_m=work_range, reference_zero_ratio=spec.reference_zero)
        runs[key] = simulate_closed_loop(law, plant, reference, noise)
        if progress is not None:
            progress()
    return runs
