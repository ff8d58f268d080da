"""Experiment-based calibration (Sec. 3.2.2): K at measured equilibria by eq. (16) or (18), fitted as eq. (17).

At a measured equilibrium (hbar_eq, |a|_eq) the film carries the weight plus any downward magnetic
force, pi r0^2 p_a (|a| / hbar)^2 K(sigma(hbar)) = m g + F_mag, which is eq. (18) multiplied by
m omega^2 h0 (eq. 16 when F_mag = 0). Each row of measurements gives one K; a least-squares polynomial
in sigma of the form of eq. (17) is the calibration.
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np

from nfal.csvdata import read_numeric_csv
from nfal.errors import DataFormatError, InvalidParameterError, require_positive

from .calibration import PolynomialK
from .plausibility import MAX_CLEARANCE_M, MAX_EXCITATION_M, require_plausible
from .rig import RigParameters


@dataclasses.dataclass(frozen=True)
class VoltageAmplitudeMap:
    """The drive voltage amplitude V [V] to excitation norm |a| [m] (the paper's second experiment set).

    Either a gain (|a| = gain * V) or a measured table of (V, |a|) pairs, interpolated linearly.
    """

    voltage: np.ndarray
    amplitude: np.ndarray

    @classmethod
    def linear(cls, metres_per_volt: float) -> "VoltageAmplitudeMap":
        gain = require_positive("metres_per_volt", metres_per_volt)
        return cls(np.array([0.0, 1.0]), np.array([0.0, gain]))

    @classmethod
    def from_csv(cls, path: str | os.PathLike) -> "VoltageAmplitudeMap":
        """A CSV of (voltage_v, amplitude_m) rows with increasing values."""
        _, table = read_numeric_csv(path)
        if table.shape[1] != 2 or table.shape[0] < 2:
            raise DataFormatError(f"{path}: a voltage map has two columns (voltage_v, amplitude_m) and >= 2 rows")
        if np.any(np.diff(table[:, 0]) <= 0) or np.any(np.diff(table[:, 1]) <= 0):
            raise DataFormatError(f"{path}: voltage and amplitude must both increase down the table")
        return cls(table[:, 0], table[:, 1])

    def __call__(self, voltage):
        """|a| [m] for drive voltage amplitudes ``voltage`` [V] (linear beyond the table's ends)."""
        voltage = np.asarray(voltage, dtype=float)
        slope_low = (self.amplitude[1] - self.amplitude[0]) / (self.voltage[1] - self.voltage[0])
        slope_high = (self.amplitude[-1] - self.amplitude[-2]) / (self.voltage[-1] - self.voltage[-2])
        inside = np.interp(voltage, self.voltage, self.amplitude)
        below = self.amplitude[0] + slope_low * (voltage - self.voltage[0])
        above = self.amplitude[-1] + slope_high * (voltage - self.voltage[-1])
        return np.where(voltage < self.voltage[0], below, np.where(voltage > self.voltage[-1], above, inside))


@dataclasses.dataclass(frozen=True)
class EquilibriumData:
    """Measured equilibria: clearance [m], excitation norm |a| [m], downward magnetic force [N]."""

    height: np.ndarray
    excitation: np.ndarray
    magnetic_force: np.ndarray

    def __post_init__(self) -> None:
        n = self.height.size
        if n < 2 or self.excitation.size != n or self.magnetic_force.size != n:
            raise DataFormatError("equilibrium data needs >= 2 rows with a height and an excitation each")
        if np.any(self.height <= 0) or np.any(self.excitation <= 0):
            raise DataFormatError("measured heights and excitations must all be > 0")
        if not (np.all(np.isfinite(self.excitation)) and np.all(np.isfinite(self.magnetic_force))):
            raise DataFormatError("measured excitations and magnetic forces must be finite numbers")
        require_plausible("measured height", float(np.max(self.height)), MAX_CLEARANCE_M, "m")
        require_plausible("measured excitation", float(np.max(self.excitation)), MAX_EXCITATION_M, "m")

    @classmethod
    def from_csv(cls, path: str | os.PathLike, voltage_map: VoltageAmplitudeMap | None = None) -> "EquilibriumData":
        """Read columns ``height_m`` and ``excitation_m`` (or ``voltage_v`` with a voltage map),
        optionally ``magnetic_force_n`` (downward axial magnetic force, eq. 18)."""
        names, table = read_numeric_csv(path)
        column = {name: table[:, i] for i, name in enumerate(names)}
        if "height_m" not in column:
            raise DataFormatError(f"{path}: needs a column height_m (found {', '.join(names)})")
        if "excitation_m" in column:
            excitation = column["excitation_m"]
        elif "voltage_v" in column:
            if voltage_map is None:
                raise DataFormatError(f"{path}: has voltage_v but no voltage-to-amplitude map was given")
            excitation = voltage_map(column["voltage_v"])
        else:
            raise DataFormatError(f"{path}: needs a column excitation_m or voltage_v (found {', '.join(names)})")
        magnetic = column.get("magnetic_force_n", np.zeros_like(column["height_m"]))
        return cls(column["height_m"], np.asarray(excitation, dtype=float), magnetic)


@dataclasses.dataclass(frozen=True)
class ExperimentalCalibration:
    """K at each measured equilibrium and the fitted polynomial of eq. (17)."""

    sigma: np.ndarray
    measured_K: np.ndarray
    fit: PolynomialK

    @property
    def residuals(self) -> np.ndarray:
        """Measured K minus the fitted K, per point."""
        return self.measured_K - self.fit(self.sigma)

    def report(self) -> dict:
        residuals = self.residuals
        return {
            "coefficients": self.fit.coefficients.tolist(),
            "sigma_range": list(self.fit.sigma_range),
            "sigma": self.sigma.tolist(),
            "K": self.measured_K.tolist(),
            "residuals": residuals.tolist(),
            "residual_rms": float(np.sqrt(np.mean(residuals**2))),
            "residual_max": float(np.max(np.abs(residuals))),
        }


def measured_K(rig: RigParameters, data: EquilibriumData) -> tuple[np.ndarray, np.ndarray]:
    """(sigma, K) at each equilibrium by eq. (18) (eq. 16 where the magnetic force is zero)."""
    delta = data.excitation / data.height
    K = (rig.mass * rig.gravity + data.magnetic_force) / (rig.film_force_scale * delta**2)
    return rig.squeeze_number(data.height), K


#: The degree of eq. (17)'s polynomial K(sigma): a fit of it needs one more distinct height than this.
FIT_DEGREE = 4


def fit_calibration(rig: RigParameters, data: EquilibriumData, degree: int = FIT_DEGREE) -> ExperimentalCalibration:
    """Least-squares polynomial K(sigma) of ``degree`` (4 in eq. 17) through the measured K values."""
    if not isinstance(degree, (int, np.integer)) or degree < 0:
        raise InvalidParameterError("degree", degree, "a whole number >= 0")
    sigma, K = measured_K(rig, data)
    if np.unique(sigma).size <= degree:
        raise InvalidParameterError("degree", degree,
                                    f"below the number of distinct heights measured ({np.unique(sigma).size})")
    order = np.argsort(sigma)
    sigma, K = sigma[order], K[order]
    series = np.polynomial.Polynomial.fit(sigma, K, degree)  # scaled domain: well conditioned
    coefficients = series.convert().coef  # ascending powers of sigma, as eq. (17)
    fit = PolynomialK(coefficients, (sigma[0], sigma[-1]), name=f"experimental fit, degree {degree}")
    return ExperimentalCalibration(sigma, K, fit)
