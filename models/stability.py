"""The local stability map of Fig. 8: design height x operating height -> discrete pole closest to |z| = 1.

For a design height h_d and an operating height h_o the local loop is the plant of eq. (20) at h_o with
the gains of eqs. (21)-(22) designed at h_d (:mod:`nfal.models.local_loop`: its state, and its two
discretisations at the sampling period T_s, Table 2: 2 kHz: ``"forward_euler"``, the paper's Fig. 8, and
``"zoh"``, the realised digital loop).

Because trace(A) = -(alpha1 + omega_L) does not depend on the gains, the forward-Euler loop can only be
stable where alpha1 + omega_L < 8 / T_s (every |1 + T_s s| < 1 needs Re s > -2 / T_s): with the paper's
rig and Table 2 that excludes clearances below about 65 um whatever the gains (docs/controller.md).
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from nfal.errors import InvalidParameterError, require_positive

from .calibration import CalibrationFunction, paper_calibration
from .local_loop import DISCRETISATIONS, continuous_loop_matrix, discrete_loop_matrix
from .lpv import LPVCoefficients, lpv_coefficients
from .pid_design import DesignSpec, GainSchedule, design_at
from .plant import DampingModel
from .rig import RigParameters
from .table2 import SAMPLING_RATE_HZ, WORK_RANGE_M

logger = logging.getLogger(__name__)

__all__ = ["StabilityMap", "continuous_loop_matrix", "discrete_loop_matrix", "max_pole_modulus", "stability_map",
           "diagonal_moduli", "realizable_schedule", "DISCRETISATIONS"]


@dataclasses.dataclass(frozen=True)
class StabilityMap:
    """Fig. 8: ``max_pole_modulus[i, j]`` for design height ``design_height_m[i]`` and operating
    height ``operating_height_m[j]`` [m] (largest |z| of the discrete closed loop); ``placement`` is
    the loop the designs placed the poles of ("continuous" or "sampled")."""

    design_height_m: np.ndarray
    operating_height_m: np.ndarray
    max_pole_modulus: np.ndarray
    discretisation: str
    sample_rate_hz: float
    placement: str = "continuous"

    def to_dict(self) -> dict:
        return {"design_height_m": self.design_height_m.tolist(),
                "operating_height_m": self.operating_height_m.tolist(),
                "max_pole_modulus": self.max_pole_modulus.tolist()}


def max_pole_modulus(plant: LPVCoefficients, gains, omega_lpf: float, step: float,
                     discretisation: str = "forward_euler") -> float:
    """Largest |z| of the discrete local loop: < 1 means locally stable."""
    return float(np.max(np.abs(np.linalg.eigvals(discrete_loop_matrix(plant, gains, omega_lpf, step, discretisation)))))


def stability_map(design_heights_m=None, operating_heights_m=None, rig: RigParameters | None = None,
                  calibration: CalibrationFunction | None = None, spec: DesignSpec | None = None, *,
                  sample_rate_hz: float = SAMPLING_RATE_HZ, discretisation: str = "forward_euler",
                  damping: DampingModel | None = None) -> StabilityMap:
    """Fig. 8 over a grid of design and operating heights [m] (default 50-200 um every 5 um for both).

    Parameters
    ----------
    design_heights_m, operating_heights_m : array_like, optional
        Clearances [m] where the controller is designed and where the plant is linearised.
    rig, calibration, spec, damping : optional
        Design and plant model (default: the paper's rig, eq. (17), Table 2's continuous design, eq. (6)).
        With ``spec.sample_rate_hz`` set (a sampled design) the map of the realised loop is ``"zoh"``.
    sample_rate_hz : float
        Sampling rate of the digital loop [Hz] (Table 2: 2000).
    discretisation : {"forward_euler", "zoh"}
        See the module docstring.
    """
    rig, calibration, spec = rig or RigParameters(), calibration or paper_calibration(), spec or DesignSpec()
    default = np.linspace(*WORK_RANGE_M, 31)
    design_h = np.asarray(default if design_heights_m is None else design_heights_m, dtype=float).ravel()
    operating_h = np.asarray(default if operating_heights_m is None else operating_heights_m, dtype=float).ravel()
    step = rig.omega / require_positive("sample_rate_hz", sample_rate_hz)
    if discretisation not in DISCRETISATIONS:
        raise InvalidParameterError("discretisation", discretisation, f"one of {DISCRETISATIONS}")
    design_lpv = lpv_coefficients(design_h, rig, calibration, damping=damping)
    operating_lpv = lpv_coefficients(operating_h, rig, calibration, damping=damping)
    designs = [design_at(design_lpv.at(i), spec, rig) for i in range(design_h.size)]
    wl = spec.omega_lpf(rig)
    moduli = np.array([[max_pole_modulus(operating_lpv.at(j), (d.kp, d.ki, d.kd), wl, step, discretisation)
                        for j in range(operating_h.size)] for d in designs])
    logger.info("stability map (%s): max |z| from %.4f to %.4f", discretisation, moduli.min(), moduli.max())
    placement = "continuous" if spec.sample_rate_hz is None else "sampled"
    return StabilityMap(design_h, operating_h, moduli, discretisation, float(sample_rate_hz), placement)


def diagonal_moduli(schedule: GainSchedule, rig: RigParameters | None = None, *,
                    sample_rate_hz: float = SAMPLING_RATE_HZ, discretisation: str = "forward_euler") -> np.ndarray:
    """max |z| of the local loop at each design of ``schedule``, operated at its own design height."""
    rig = rig or RigParameters()
    step = rig.omega / require_positive("sample_rate_hz", sample_rate_hz)
    return np.array([max_pole_modulus(d.lpv, (d.kp, d.ki, d.kd), d.omega_lpf, step, discretisation)
                     for d in schedule.designs])


def realizable_schedule(schedule: GainSchedule, rig: RigParameters | None = None, *,
                        sample_rate_hz: float = SAMPLING_RATE_HZ,
                        discretisation: str = "forward_euler") -> GainSchedule:
    """``schedule`` cut to the heights where the digital loop realises the continuous design.

    Keeps the designs from the lowest height h_f upwards such that every design at or above h_f is
    locally stable at its own height in the sense of Fig. 8 (``discretisation``, ``sample_rate_hz``);
    below h_f the trimmed schedule holds the gains of h_f (the scheduling variable is clamped). With the
    paper's rig and Table 2, h_f is 90 um on a 5 um grid (docs/controller.md).
    """
    moduli = diagonal_moduli(schedule, rig, sample_rate_hz=sample_rate_hz, discretisation=discretisation)
    unstable = np.flatnonzero(moduli >= 1.0)
    first = 0 if unstable.size == 0 else int(unstable[-1]) + 1
    if len(schedule.designs) - first < 4:
        raise InvalidParameterError("schedule", f"{len(schedule.designs) - first} realisable designs",
                                    f"at least 4 designs whose {discretisation} loop at {sample_rate_hz:g} Hz "
                                    "is stable")
    if first:
        logger.info("digital loop at %g Hz cannot realise the designs below %.1f um (%s |z| up to %.3g): "
                    "gains held there", sample_rate_hz, schedule.heights_m[first] * 1e6, discretisation,
                    moduli[:first].max())
    trimmed = GainSchedule(schedule.designs[first:])
    trimmed.name = f"gain-scheduled from {schedule.heights_m[first] * 1e6:.0f} um"
    return trimmed
