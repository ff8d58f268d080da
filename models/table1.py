"""Table 1 and Fig. 5: the simplified model (13) with the numerical K against the full model (3)-(5).

Each case releases the object from rest at ``RELEASE_RATIO`` times the simplified model's equilibrium
and runs both models for ``SETTLING_TIME_CONSTANTS`` slow time constants of the linearised plant, so
that what is left of the transient is below 1e-5 of the height. No magnetic force (as the paper).
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from .calibration import TabulatedK, perturbation_calibration
from .coupled import CoupledModel
from .excitation import ExcitationShape, paper_shape
from .paper_numbers import paper_value
from .plant import SimplifiedPlant
from .rig import RigParameters

RELEASE_RATIO = 1.25
SETTLING_TIME_CONSTANTS = 10.0


@dataclasses.dataclass(frozen=True)
class Table1Case:
    """One row of Table 1: the rig's mass [kg], frequency [Hz] and |a| [m], with the paper's results."""

    name: str
    mass: float
    frequency: float
    excitation: float
    paper_delta: float
    paper_error_percent: float


def _paper_case(name: str) -> Table1Case:
    value = {field: paper_value(f"table1.{name}.{field}") for field in ("mass", "frequency", "excitation", "delta",
                                                                         "error")}
    return Table1Case(name, value["mass"], value["frequency"], value["excitation"], value["delta"], value["error"])


#: The four cases of Table 1, from the paper's numbers (``data/paper_numbers.json``).
TABLE1 = tuple(_paper_case(name) for name in "abcd")


@dataclasses.dataclass(frozen=True)
class Table1Result:
    """Both models' steady state and their release-from-rest responses (Fig. 5) for one case."""

    case: Table1Case
    delta_simplified: float
    delta_full: float
    time_simplified: np.ndarray
    height_simplified: np.ndarray
    time_full: np.ndarray
    height_full: np.ndarray

    @property
    def error_percent(self) -> float:
        """Steady-state error: |hbar_simplified - hbar_full| / hbar_full, in percent."""
        return 100.0 * abs(self.delta_full / self.delta_simplified - 1.0)

    def summary(self) -> dict:
        return {"case": self.case.name, "delta_simplified": self.delta_simplified, "delta_full": self.delta_full,
                "error_percent": self.error_percent, "paper_delta": self.case.paper_delta,
                "paper_error_percent": self.case.paper_error_percent}


def slow_time_constant(plant: SimplifiedPlant, height: float, excitation: float) -> float:
    """The slowest time constant [s] of eq. (13) linearised at an equilibrium (central differences)."""
    dh, dv = 1e-6 * height, 1e-6
    a_h = (plant.acceleration(height + dh, 0.0, excitation)
           - plant.acceleration(height - dh, 0.0, excitation)) / (2 * dh)
    a_v = (plant.acceleration(height, dv, excitation) - plant.acceleration(height, -dv, excitation)) / (2 * dv)
    rates = np.linalg.eigvals(np.array([[0.0, 1.0], [float(a_h), float(a_v)]]))
    return 1.0 / float(np.min(np.abs(rates.real)))


def run_case(case: Table1Case, shape: ExcitationShape | None = None, calibration: TabulatedK | None = None,
             rig: RigParameters | None = None, nodes: int = 101, steps_per_period: int = 256,
             progress: Callable[[int, int], None] | None = None) -> Table1Result:
    """Run one case of Table 1 with both models (the shape defaults to the paper's, Fig. 3)."""
    shape = shape or paper_shape()
    calibration = calibration or perturbation_calibration(shape)
    rig = (rig or RigParameters()).replace(mass=case.mass, frequency=case.frequency)
    plant = SimplifiedPlant(rig, calibration)
    height = plant.equilibrium_height(case.excitation)
    duration = SETTLING_TIME_CONSTANTS * slow_time_constant(plant, height, case.excitation)
    release = RELEASE_RATIO * height
    simplified = plant.simulate(duration, case.excitation, release, samples=1001)
    full = CoupledModel(rig, shape, nodes=nodes, steps_per_period=steps_per_period, envelope=True).simulate(
        duration, case.excitation, release, progress=progress)
    return Table1Result(case, case.excitation / height, case.excitation / float(full.height[-1]),
                        simplified.time, simplified.height, full.time, full.height)
