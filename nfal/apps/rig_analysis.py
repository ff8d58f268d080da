"""What ``nfal identify`` makes of its experiments: K(sigma) from the equilibria by eq. (16) with its fit of the
form of eq. (17), and the damping over eq. (6) from the drive steps (Sec. 3.2.2, 3.3). The numerics are
:mod:`nfal.models.identification`'s and :mod:`nfal.models.measured_calibration`'s; this gathers them into a
calibration file.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from nfal.apps.rig_experiments import DriveStep, Equilibrium
from nfal.models.calibration import RigCalibration, rig_record
from nfal.models.damping import DampingCorrection
from nfal.models.identification import AMPLITUDE_TIME_CONSTANT_S, StepFit, damping_table, fit_step
from nfal.models.measured_calibration import FIT_DEGREE, EquilibriumData, ExperimentalCalibration, fit_calibration
from nfal.models.rig import RigParameters


@dataclasses.dataclass(frozen=True)
class Identification:
    """What the experiments identified: K(sigma) (eqs. 16-17), the damping table, and the data behind them."""

    calibration: ExperimentalCalibration
    equilibria: list[Equilibrium]
    damping: DampingCorrection
    rig: RigParameters
    step_fits: list[list[StepFit]]
    steps: list[list[DriveStep]]
    metres_per_volt: float

    def document(self, provenance: dict) -> dict:
        """The calibration file (:class:`RigCalibration`: K, ``damping``, the ``rig`` it was identified on and
        ``provenance``), plus the ``equilibria`` behind K."""
        calibration = RigCalibration(self.calibration.fit, self.damping, rig_record(self.rig), provenance)
        return {**calibration.to_dict(),
                "equilibria": {"voltage_v": [p.voltage for p in self.equilibria],
                               "height_m": [p.height for p in self.equilibria],
                               "height_spread_m": [p.spread for p in self.equilibria],
                               "metres_per_volt": self.metres_per_volt}}


def analyse(equilibria: list[Equilibrium], steps: list[list[DriveStep]], rig: RigParameters, *, metres_per_volt: float,
            lag_s: float = AMPLITUDE_TIME_CONSTANT_S, degree: int = FIT_DEGREE) -> Identification:
    """K at each equilibrium by eq. (16) with |a| = ``metres_per_volt`` V, its fit of the form of eq. (17), and
    the damping factor over eq. (6) at each step height with its 95 % interval."""
    data = EquilibriumData(np.array([p.height for p in equilibria]),
                           metres_per_volt * np.array([p.voltage for p in equilibria]), np.zeros(len(equilibria)))
    calibration = fit_calibration(rig, data, degree)
    fits = [[fit_step(s.times, s.heights, metres_per_volt * s.voltage_before, metres_per_volt * s.voltage_after, rig,
                      lag_s)
             for s in at_height] for at_height in steps]
    return Identification(calibration, equilibria, damping_table(fits), rig, fits, steps, metres_per_volt)
