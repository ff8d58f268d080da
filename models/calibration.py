"""Calibration functions K(sigma) of eq. (12): polynomial (eq. 17), tabulated, and numerical sources.

Every source is a :class:`CalibrationFunction`: callable on squeeze numbers, with an exact
``derivative`` and a declared ``sigma_range``. Outside that range the value is held at the nearer
end (slope zero) so that a plant passing through never sees a diverging fit; ``in_range`` tells.

A calibration *file* (JSON) holds one K description (:meth:`CalibrationFunction.to_dict`) at its top
level and, optionally, ``"version"`` (:data:`CALIBRATION_FILE_VERSION`; absent in files of older
releases), ``"rig"`` (the rig parameters the identification assumed, checked against the rig a
design or a plant uses), ``"damping"`` (a :class:`~nfal.models.damping.DampingCorrection` of eq. (6))
and ``"provenance"`` (free-form: date, port, firmware, raw data file; carried, never interpreted).
:func:`load_rig_calibration` reads all of it as a :class:`RigCalibration`; :func:`load_calibration`
only K.
"""

from __future__ import annotations

import abc
import dataclasses
import json
import math
import os
from pathlib import Path

import numpy as np
import scipy

from nfal.errors import DataFormatError, InvalidParameterError
from nfal.csvdata import read_user_text

from . import piecewise
from .damping import DampingCorrection
from .excitation import ExcitationShape
from .json_fields import as_json, json_number, json_numbers
from .paper_numbers import paper_value
from .perturbation import DEFAULT_NODES, as_squeeze_numbers, perturbation_K
from .rig import RigParameters
from .scalar_spline import ScalarSpline

#: Eq. (17): the paper's fit to its measured K, ascending powers of sigma.
PAPER_COEFFICIENTS = tuple(paper_value(f"eq17.c{power}") for power in range(5))
#: The squeeze numbers over which eq. (17) is used. Not stated in the paper; the quartic is smooth and
#: positive there and collapses past 500 (K(600) = 0.2). Covers the 50-200 um work range (sigma 24-384).
PAPER_SIGMA_RANGE = (10.0, 500.0)
#: The calibration file format this code reads and writes (a file without ``"version"`` is read as 1).
CALIBRATION_FILE_VERSION = 1
#: A calibration file's entries (``"equilibria"``: the data behind an identification's K, carried, not read).
FILE_KEYS = ("version", "kind", "name", "coefficients", "sigma_range", "sigma", "K", "damping", "rig", "provenance",
             "equilibria")
#: The rig parameters a calibration file's ``"rig"`` may name, and the relative mismatch that makes it
#: another rig's (K by eq. (16) and the damping factor depend on all of them; h0 only scales).
CHECKED_RIG_FIELDS = ("mass", "radius", "frequency", "viscosity", "ambient_pressure", "gravity")
RIG_MATCH_TOLERANCE = 1e-6


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

    def scalar(self, sigma: float) -> float:
        """K at one squeeze number, as :meth:`__call__` (the plants' inner loops call this)."""
        return float(self(sigma))

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

    def curve(self) -> tuple:
        """K as the piecewise polynomial of compiled code (:mod:`nfal.models.slow_kernels`)."""
        raise NotImplementedError

    def save(self, path: str | os.PathLike) -> None:
        """Write the calibration as a calibration file (read back with :func:`load_calibration`)."""
        RigCalibration(self).save(path)


class PolynomialK(CalibrationFunction):
    """K(sigma) = sum_k c_k sigma^k, the form of eq. (17); coefficients in ascending powers."""

    def __init__(self, coefficients, sigma_range: tuple[float, float], name: str = "polynomial") -> None:
        super().__init__(sigma_range, name)
        coefficients = np.asarray(coefficients, dtype=float)
        if coefficients.ndim != 1 or coefficients.size == 0 or not np.all(np.isfinite(coefficients)):
            raise InvalidParameterError("coefficients", coefficients, "one or more finite numbers")
        self.coefficients = coefficients
        self._slope_coefficients = np.polynomial.polynomial.polyder(coefficients)
        self._horner = [float(c) for c in coefficients[::-1]]

    def scalar(self, sigma: float) -> float:
        sigma = min(max(sigma, self.sigma_range[0]), self.sigma_range[1])
        value = 0.0
        for c in self._horner:
            value = value * sigma + c
        return value

    def curve(self) -> tuple:
        return piecewise.curve(False, [0.0, 1.0], np.reshape(self._horner, (1, 1, -1)), *self.sigma_range, 0.0)

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
        self._spline = scipy.interpolate.CubicSpline(np.log(sigma), values)
        self._spline_slope = self._spline.derivative()
        self._scalar_spline = ScalarSpline.of(self._spline)

    def scalar(self, sigma: float) -> float:
        return self._scalar_spline(math.log(min(max(sigma, self.sigma_range[0]), self.sigma_range[1])))

    def curve(self) -> tuple:
        return piecewise.spline_curve(self._spline, True, *self.sigma_range)

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
    """Rebuild a calibration from :meth:`CalibrationFunction.to_dict` output (read as JSON: every number exactly a
    number, the name a string; an error names the field, its value and what it must be)."""
    if not isinstance(data, dict):
        raise DataFormatError(f"a calibration description is a JSON object, not {type(data).__name__}")
    kind, name = data.get("kind"), data.get("name", data.get("kind"))
    if "kind" not in data:
        raise DataFormatError("not a calibration description: no 'kind' ('polynomial' or 'table')")
    if kind not in ("polynomial", "table"):
        raise DataFormatError(f"unknown calibration kind {as_json(kind)}: expected 'polynomial' or 'table'")
    if not isinstance(name, str):
        raise InvalidParameterError("name", name, "a string", as_shown=as_json(name))
    try:
        if kind == "polynomial":
            sigma_range = json_numbers("sigma_range", data["sigma_range"])
            if len(sigma_range) != 2:
                raise InvalidParameterError("sigma_range", sigma_range, "two squeeze numbers [low, high]")
            return PolynomialK(json_numbers("coefficients", data["coefficients"]), tuple(sigma_range), name=name)
        return TabulatedK(json_numbers("sigma", data["sigma"]), json_numbers("K", data["K"]), name=name)
    except KeyError as exc:
        raise DataFormatError(f"a calibration of kind {as_json(kind)} needs {exc}") from None


@dataclasses.dataclass(frozen=True)
class RigCalibration:
    """Everything a calibration file holds (see the module docstring).

    Attributes
    ----------
    calibration : CalibrationFunction
        K(sigma) of eq. (12).
    damping : DampingCorrection or None
        The identified multiplier of eq. (6)'s damping; None: eq. (6) as it is.
    rig : dict or None
        The rig parameters (names of :data:`CHECKED_RIG_FIELDS`, SI) the identification assumed.
    provenance : dict
        Free-form record of where the calibration came from.
    """

    calibration: CalibrationFunction
    damping: DampingCorrection | None = None
    rig: dict | None = None
    provenance: dict = dataclasses.field(default_factory=dict)

    def check_rig(self, rig: RigParameters, source: str = "the calibration") -> None:
        """Raise :class:`DataFormatError` if the file's ``"rig"`` differs from ``rig`` (more than
        :data:`RIG_MATCH_TOLERANCE` relative in a field of :data:`CHECKED_RIG_FIELDS`)."""
        if self.rig is None:
            return
        differ = [f"{name} {self.rig[name]:g} there, {getattr(rig, name):g} here" for name in CHECKED_RIG_FIELDS
                  if name in self.rig
                  and not math.isclose(self.rig[name], getattr(rig, name), rel_tol=RIG_MATCH_TOLERANCE)]
        if differ:
            raise DataFormatError(f"{source} was identified on another rig ({'; '.join(differ)}): identify this rig "
                                  "(nfal identify) or give its parameters")

    def to_dict(self) -> dict:
        data = {"version": CALIBRATION_FILE_VERSION, **self.calibration.to_dict()}
        if self.damping is not None:
            data["damping"] = self.damping.to_dict()
        if self.rig is not None:
            data["rig"] = dict(self.rig)
        if self.provenance:
            data["provenance"] = self.provenance
        return data

    def save(self, path: str | os.PathLike) -> None:
        """Write the calibration file (read back with :func:`load_rig_calibration`)."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n", encoding="utf-8")


def rig_record(rig: RigParameters) -> dict[str, float]:
    """The ``"rig"`` entry of a calibration file identified on ``rig``: every field that
    :meth:`RigCalibration.check_rig` checks."""
    return {name: float(getattr(rig, name)) for name in CHECKED_RIG_FIELDS}


def rig_record_from_dict(data: dict) -> dict[str, float]:
    """A calibration file's ``"rig"`` (:func:`rig_record`): some of :data:`CHECKED_RIG_FIELDS`, each a JSON number that
    :class:`RigParameters` accepts (> 0, and plausible: not grams as kg, nor kHz as Hz)."""
    if not isinstance(data, dict) or not set(data) <= set(CHECKED_RIG_FIELDS):
        raise DataFormatError(f"rig = {as_json(data)} is invalid: must map some of {', '.join(CHECKED_RIG_FIELDS)} to "
                              "numbers (SI)")
    record = {name: json_number(f"rig.{name}", value) for name, value in data.items()}
    for name, value in record.items():
        try:
            RigParameters(**{name: value})
        except InvalidParameterError as exc:
            raise exc.within("rig") from None
    return record


def rig_calibration_from_dict(data: dict) -> RigCalibration:
    """Read a calibration file's content (:meth:`RigCalibration.to_dict`); a K-only description is one too.
    Each field is checked: a number is a JSON number (not ``true``, not ``"1"``), and lengths, heights and the rig
    in their plausible ranges (a damping table in um is a unit slip, not a rig)."""
    if not isinstance(data, dict):
        raise DataFormatError(f"a calibration file holds a JSON object, not {type(data).__name__}")
    unknown = sorted(set(data) - set(FILE_KEYS))
    if unknown:
        raise DataFormatError(f"unknown entries {unknown} in a calibration file: it holds {', '.join(FILE_KEYS)}")
    version = data.get("version", CALIBRATION_FILE_VERSION)
    if type(version) is not int or version != CALIBRATION_FILE_VERSION:
        raise InvalidParameterError("version", version, f"{CALIBRATION_FILE_VERSION}, the file format this nfal reads "
                                    "(re-identify, or update nfal)", as_shown=as_json(version))
    rig = None if data.get("rig") is None else rig_record_from_dict(data["rig"])
    provenance = data.get("provenance", {})
    if not isinstance(provenance, dict):
        raise DataFormatError(f"provenance = {as_json(provenance)} is invalid: must be a JSON object (free-form: date, "
                              "port, firmware, raw data)")
    damping = None if data.get("damping") is None else DampingCorrection.from_dict(data["damping"])
    return RigCalibration(calibration_from_dict(data), damping, rig, provenance)


def load_rig_calibration(path: str | os.PathLike, rig: RigParameters | None = None) -> RigCalibration:
    """Read a calibration file: K, the optional damping correction, rig and provenance.

    Parameters
    ----------
    path : path-like
        A file written by :meth:`RigCalibration.save`, ``nfal calibrate`` or ``nfal identify``.
    rig : RigParameters, optional
        The rig the calibration is used for: a file identified on another one is refused.

    Raises
    ------
    DataFormatError
        Unreadable file, unknown version, bad content, or another rig's calibration.
    """
    text = read_user_text(path, "calibration")
    try:
        data = json.loads(text)
    except (ValueError, RecursionError) as exc:  # not JSON, or nested deeper than the parser goes
        raise DataFormatError(f"cannot read calibration {path}: not the JSON file that nfal calibrate --out or nfal "
                              f"identify --out writes ({exc or 'nested too deeply'})") from None
    try:
        loaded = rig_calibration_from_dict(data)
        require_lift(loaded.calibration, "K")
    except (DataFormatError, InvalidParameterError) as exc:
        raise DataFormatError(f"calibration {path}: {exc}") from None
    if rig is not None:
        loaded.check_rig(rig, f"calibration {path}")
    return loaded


def load_calibration(path: str | os.PathLike) -> CalibrationFunction:
    """K(sigma) of a calibration file (its damping, rig and provenance, if any, are read and dropped)."""
    return load_rig_calibration(path).calibration


def require_lift(calibration: CalibrationFunction, where: str) -> CalibrationFunction:
    """Return ``calibration`` unless K(sigma) <= 0 over its whole sigma range (the film never pushes: eq. (16)
    has no equilibrium anywhere), which :class:`DataFormatError` refuses."""
    low, high = calibration.sigma_range
    if not np.any(calibration(np.geomspace(low, high, 200)) > 0.0):
        raise DataFormatError(f"{where}: K(sigma) <= 0 over the whole range sigma = {low:g}-{high:g}: the film never "
                              "pushes, no object levitates (eq. 16); K > 0 is needed at the work heights")
    return calibration
