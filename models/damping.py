"""A measured correction of eq. (6)'s squeeze-film damping: a table of factors over the clearance.

Sec. 3.3: eq. (6) fits the rig at small gaps and underestimates its damping at large ones. An
identification (``nfal identify``) measures the multiplier f(h) of eq. (6)'s c(h) at a few clearances,
with a 95 % confidence band; :class:`DampingCorrection` interpolates it monotonically (PCHIP on log f,
so a monotone table gives a monotone, positive, C1 correction) and holds the end values outside the
table. It is interchangeable with the parametric :class:`~nfal.models.plant.ExcessDamping` wherever a
plant or the LPV model of eq. (20) takes ``excess_damping``/``damping``: both have ``factor(height)``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import scipy

from nfal.errors import DataFormatError, InvalidParameterError, shown

from . import piecewise
from .json_fields import as_json, json_numbers
from .plausibility import require_clearances
from .scalar_spline import ScalarSpline


#: The fields of a damping table (a calibration file's ``"damping"``).
FIELDS = ("heights_m", "factors", "factors_low", "factors_high")


@dataclasses.dataclass(frozen=True, eq=False)
class DampingCorrection:
    """The damping of eq. (6) times f(h), f tabulated at ``heights_m`` with a confidence band.

    Parameters
    ----------
    heights_m : array_like
        Identified clearances [m], strictly increasing, at least 2, each within 1 um-1 mm
        (:data:`~nfal.models.plausibility.WORK_CLEARANCES_M`: a table in um is refused, not held at one factor).
    factors : array_like
        Measured multiplier f of eq. (6)'s c(h) at each clearance (> 0).
    factors_low, factors_high : array_like, optional
        Lower and upper ends of its 95 % confidence interval (default: the factors themselves).
    """

    heights_m: np.ndarray
    factors: np.ndarray
    factors_low: np.ndarray | None = None
    factors_high: np.ndarray | None = None

    def __post_init__(self) -> None:
        heights = require_clearances("heights_m", _finite_row("heights_m", self.heights_m))
        factors = _finite_row("factors", self.factors)
        low = factors if self.factors_low is None else _finite_row("factors_low", self.factors_low)
        high = factors if self.factors_high is None else _finite_row("factors_high", self.factors_high)
        if heights.size < 2 or any(v.size != heights.size for v in (factors, low, high)):
            raise DataFormatError(f"a damping table needs >= 2 heights and one factor (and band) per height, got "
                                  f"{heights.size} heights, {factors.size} factors, {low.size}/{high.size} band ends")
        if np.any(np.diff(heights) <= 0):
            raise DataFormatError(f"damping heights_m must be strictly increasing, got {shown(heights)}")
        if np.any(low <= 0) or np.any(low > factors) or np.any(factors > high):
            raise DataFormatError("damping factors must satisfy 0 < factors_low <= factors <= factors_high, got "
                                  f"{shown(low)}, {shown(factors)}, {shown(high)}")
        for name, value in (("heights_m", heights), ("factors", factors), ("factors_low", low), ("factors_high", high)):
            value.flags.writeable = False
            object.__setattr__(self, name, value)
        spline = scipy.interpolate.PchipInterpolator(heights, np.log(factors))
        object.__setattr__(self, "_log_factor", spline)
        object.__setattr__(self, "_scalar_log_factor", ScalarSpline.of(spline))  # for factor_scalar

    @property
    def height_range_m(self) -> tuple[float, float]:
        return float(self.heights_m[0]), float(self.heights_m[-1])

    def factor(self, height):
        """f at the clearance(s) ``height`` [m] (held at the end values outside the table)."""
        return np.exp(self._log_factor(np.clip(np.asarray(height, dtype=float), *self.height_range_m)))

    def log_factor_curve(self) -> tuple:
        """log f of h as the piecewise polynomial of compiled code (:mod:`nfal.models.piecewise`)."""
        return piecewise.spline_curve(self._log_factor, False, *self.height_range_m)

    def factor_band(self, height) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) ends of the confidence band at ``height`` [m], interpolated like the factor."""
        clipped = np.clip(np.asarray(height, dtype=float), *self.height_range_m)
        return tuple(np.exp(scipy.interpolate.PchipInterpolator(self.heights_m, np.log(band))(clipped))
                     for band in (self.factors_low, self.factors_high))

    def factor_scalar(self, height: float) -> float:
        """:meth:`factor` at one clearance, in plain Python: plants call it per sub-step (0.5 us against
        7.7 us for :meth:`factor`)."""
        return math.exp(self._scalar_log_factor(height))

    def to_dict(self) -> dict:
        """The ``"damping"`` entry of a calibration file."""
        return {"heights_m": self.heights_m.tolist(), "factors": self.factors.tolist(),
                "factors_low": self.factors_low.tolist(), "factors_high": self.factors_high.tolist()}

    @classmethod
    def from_dict(cls, data: dict) -> "DampingCorrection":
        """Read the ``"damping"`` entry of a calibration file (:meth:`to_dict`); an error names the field
        (``damping.heights_m``), its value and what it must be."""
        if not isinstance(data, dict) or not {"heights_m", "factors"} <= set(data) <= set(FIELDS):
            raise DataFormatError(f"damping = {as_json(data)} is invalid: must hold heights_m and factors (and "
                                  "optionally factors_low, factors_high), nothing else")
        try:
            band = {name: json_numbers(name, data[name]) for name in ("factors_low", "factors_high")
                    if data.get(name) is not None}
            return cls(json_numbers("heights_m", data["heights_m"]), json_numbers("factors", data["factors"]), **band)
        except InvalidParameterError as exc:
            raise exc.within("damping") from None

    def __repr__(self) -> str:
        return (f"<DampingCorrection {self.heights_m.size} heights {self.heights_m[0] * 1e6:.0f}-"
                f"{self.heights_m[-1] * 1e6:.0f} um, factors {self.factors.min():.3g}-{self.factors.max():.3g}>")


def _finite_row(name: str, values) -> np.ndarray:
    try:
        row = np.array(values, dtype=float)
    except (TypeError, ValueError):
        raise DataFormatError(f"damping {name} must be a list of numbers, got {shown(values)}") from None
    if row.ndim != 1 or not np.all(np.isfinite(row)):
        raise DataFormatError(f"damping {name} must be a flat list of finite numbers, got {shown(values)}")
    return row
