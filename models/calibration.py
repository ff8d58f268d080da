"""Calibration functions K(sigma) of eq. (12): polynomial (eq. 17), tabulated, and numerical sources.

Every source is a :class:`CalibrationFunction`: callable on squeeze numbers, with an exact
``derivative`` and a declared ``sigma_range``. Outside that range the value is held at the nearer
end (slope zero) so that a plant passing through never sees a diverging fit; ``in_range`` tells.
"""

from __future__ import annotations

import abc
import json
import os
from pathlib import Path

import numpy as np
from scipy import interpolate

from .errors import DataFormatError, InvalidParameterError
from .excitation import ExcitationShape
from .perturbation import DEFAULT_NODES, as_squeeze_numbers, perturbation_K

#: Eq. (17): the paper's fit to its measured K, ascending powers of sigma.
PAPER_COEFFICIENTS = (1.2348, 2.2928e-2, -1.301e-4, 2.9826e-7, -2.4985e-10)
#: The squeeze numbers over which eq. (17) is used. Not stated in the paper; the quartic is smooth and
#: positive there and collapses past 500 (K(600) = 0.2). Covers the 50-200 um work range (sigma 24-384).
PAPER_SIGMA_RANGE = (10.0, 500.0)


class CalibrationFunction(abc.ABC):
    """K(sigma) with its derivative over a declared range of squeeze numbers."""

    def __init__(self, sigma_range: tuple[float, float], name: str) -> None:
        low, high = (float(v) for v in sigma_range)
        if not (0 < low < high < np.inf):
            raise InvalidParameterError("sigma_range", sigma_range, "two finite squeeze numbers 0 < low < high")
        self.sigma_range, self.name = (low, high), name

    @abc.abstractmethod
    def _value(self, sigma: np.ndarray) -> np.ndarray: ...

    @abc.abstractmethod
    def _slope(self, sigma: np.ndarray) -> np.ndarray: ...

    def __call__(self, sigma):
        """K at ``sigma`` (held at the end values outside ``sigma_range``)."""
        sigma = np.asarray(sigma, dtype=float)
        return self._value(np.clip(sigma, *self.sigma_range))

    def derivative(self, sigma):
        """dK/dsigma at ``sigma`` (zero outside ``sigma_range``)."""
        sigma = np.asarray(sigma, dtype=float)
        return np.where(self.in_range(sigma), self._slope(np.clip(sigma, *self.sigma_range)), 0.0)

    def in_range(self, sigma):
        low, high = self.sigma_range
        return (np.asarray(sigma) >= low) & (np.asarray(sigma) <= high)

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name} sigma in [{self.sigma_range[0]:g}, {self.sigma_range[1]:g}]>"

    def to_dict(self) -> dict:
        """A JSON-ready description that :func:`calibration_from_dict` reads back."""
        raise NotImplementedError

    def save(self, path: str | os.PathLike) -> None:
        """Write the calibration as JSON (read back with :func:`load_calibration`)."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n", encoding="utf-8")


class PolynomialK(CalibrationFunction):
    """K(sigma) = sum_k c_k sigma^k, the form of eq. (17); coefficients in ascending powers."""

    def __init__(self, coefficients, sigma_range: tuple[float, float], name: str = "polynomial") -> None:
        super().__init__(sigma_range, name)
        coefficients = np.asarray(coefficients, dtype=float)
        if coefficients.ndim != 1 or coefficients.size == 0 or not np.all(np.isfinite(coefficients)):
            raise InvalidParameterError("coefficients", coefficients, "one or more finite numbers")
        self.coefficients = coefficients
        self._slope_coefficients = np.polynomial.polynomial.polyder(coefficients)

    def _value(self, sigma):
        return np.polynomial.polynomial.polyval(sigma, self.coefficients)

    def _slope(self, sigma):
        return np.polynomial.polynomial.polyval(sigma, self._slope_coefficients)

    def to_dict(self) -> dict:
        return {"kind": "polynomial", "name": self.name, "coefficients": self.coefficients.tolist(),
                "sigma_range": list(self.sigma_range)}


class TabulatedK(CalibrationFunction):
    """K from a table of (sigma, K), interpolated by a C2 cubic spline in log(sigma)."""

    def __init__(self, sigma, values, name: str = "table") -> None:
        sigma, values = as_squeeze_numbers(sigma), np.asarray(values, dtype=float)
        if sigma.shape != values.shape or sigma.size < 4 or not np.all(np.isfinite(values)):
            raise DataFormatError(f"a K table needs >= 4 finite (sigma, K) pairs, got {sigma.size} and {values.size}")
        if np.any(np.diff(sigma) <= 0):
            raise DataFormatError("sigma must increase strictly down a K table")
        super().__init__((sigma[0], sigma[-1]), name)
        self.sigma, self.values = sigma, values
        self._spline = interpolate.CubicSpline(np.log(sigma), values)
        self._spline_slope = self._spline.derivative()

    def _value(self, sigma):
        return self._spline(np.log(sigma))

    def _slope(self, sigma):
        return self._spline_slope(np.log(sigma)) / sigma

    def to_dict(self) -> dict:
        return {"kind": "table", "name": self.name, "sigma": self.sigma.tolist(), "K": self.values.tolist()}


def paper_calibration() -> PolynomialK:
    """Eq. (17): the measured calibration of the paper's rig (magnetic centring included)."""
    return PolynomialK(PAPER_COEFFICIENTS, PAPER_SIGMA_RANGE, name="paper eq. (17)")


def perturbation_calibration(shape: ExcitationShape, sigma_range: tuple[float, float] = (1.0, 1e5),
                             points: int = 200, nodes: int = DEFAULT_NODES) -> TabulatedK:
    """K(sigma) of ``shape`` by the perturbation route on a log grid, as a smooth table."""
    low, high = (float(v) for v in sigma_range)
    sigma = np.geomspace(low, high, int(points))
    return TabulatedK(sigma, perturbation_K(shape, sigma, nodes), name=f"perturbation, {shape.name}")


def calibration_from_dict(data: dict) -> CalibrationFunction:
    """Rebuild a calibration from :meth:`CalibrationFunction.to_dict` output."""
    try:
        kind = data["kind"]
        if kind == "polynomial":
            return PolynomialK(data["coefficients"], tuple(data["sigma_range"]), name=data.get("name", "polynomial"))
        if kind == "table":
            return TabulatedK(data["sigma"], data["K"], name=data.get("name", "table"))
    except (KeyError, TypeError) as exc:
        raise DataFormatError(f"not a calibration description: missing or bad {exc}") from None
    raise DataFormatError(f"unknown calibration kind {data.get('kind')!r}: expected 'polynomial' or 'table'")


def load_calibration(path: str | os.PathLike) -> CalibrationFunction:
    """Read a calibration JSON file written by :meth:`CalibrationFunction.save` or ``nfal calibrate``."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:  # ValueError: not JSON, or not UTF-8 text at all
        raise DataFormatError(f"cannot read calibration {path}: {exc}") from None
    if not isinstance(data, dict):
        raise DataFormatError(f"{path}: not a calibration description (a JSON object with 'kind')")
    return require_lift(calibration_from_dict(data), str(path))


def require_lift(calibration: CalibrationFunction, where: str) -> CalibrationFunction:
    """Return ``calibration`` unless K(sigma) <= 0 over its whole sigma range (the film never pushes: eq. (16)
    has no equilibrium anywhere), which :class:`DataFormatError` refuses."""
    low, high = calibration.sigma_range
    if not np.any(calibration(np.geomspace(low, high, 200)) > 0.0):
        raise DataFormatError(f"{where}: K(sigma) <= 0 over the whole range sigma = {low:g}-{high:g}: the film never "
                              "pushes, no object levitates (eq. 16); K > 0 is needed at the work heights")
    return calibration
