"""Excitation forms eps_hat(R) of the driving surface, normalised as eq. (7): int_0^1 eps_hat^2 dR = 1.

Every shape is a callable of the normalised radius R = r / r0 in [0, 1] with a ``slope`` (d eps_hat / dR).
"""

from __future__ import annotations

import abc
import os
from importlib import resources

import numpy as np
import scipy

from nfal.csvdata import read_numeric_csv
from nfal.errors import DataFormatError, InvalidParameterError

#: This package's data folder, resolved once at import: an FMU carrying its own copy of nfal.models
#: reads its own file, not that of another copy the process holds under the same name (fmus/bundle_loader.py).
_DATA = resources.files(__package__) / "data"

PAPER_SHAPE_FILE = "fig3_mode_shape_standin.csv"



def largest_excursion(*samples: np.ndarray) -> float:
    """max |eps_hat| over the given samples (nodes, faces): the gap 1 - delta eps_hat sin T closes first where
    |eps_hat| is largest, whatever its sign."""
    return float(max(np.max(np.abs(s)) for s in samples))

class ExcitationShape(abc.ABC):
    """An axisymmetric excitation form with unit norm (eq. 7, weight 1)."""

    name: str = "shape"

    @abc.abstractmethod
    def _raw(self, R: np.ndarray) -> np.ndarray:
        """The un-normalised shape."""

    @abc.abstractmethod
    def _raw_slope(self, R: np.ndarray) -> np.ndarray:
        """d/dR of the un-normalised shape."""

    @property
    def _scale(self) -> float:
        if not hasattr(self, "_cached_scale"):
            norm_sq, _ = scipy.integrate.quad(lambda r: float(self._raw(np.array(r))) ** 2, 0.0, 1.0, limit=400)
            sign = 1.0 if float(self._raw(np.array(0.0))) >= 0 else -1.0
            self._cached_scale = sign / np.sqrt(norm_sq)
        return self._cached_scale

    def __call__(self, R) -> np.ndarray:
        return self._scale * self._raw(np.asarray(R, dtype=float))

    def slope(self, R) -> np.ndarray:
        """d eps_hat / dR."""
        return self._scale * self._raw_slope(np.asarray(R, dtype=float))

    def edge_value(self) -> float:
        """eps_hat(1): the excitation at the rim, which sets the trapped-gas limit of K."""
        return float(self(1.0))

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name}>"


class PistonShape(ExcitationShape):
    """Uniform excitation eps_hat = 1 (the rigid piston of ref. [4])."""

    name = "piston"

    def _raw(self, R):
        return np.ones_like(R)

    def _raw_slope(self, R):
        return np.zeros_like(R)


#: Most nodal circles of a plate mode: 50 circles on a 401-node grid leave 8 nodes per half-wave.
MAX_NODAL_CIRCLES = 50


class PlateModeShape(ExcitationShape):
    """n-th axisymmetric mode of a free-edge Kirchhoff circular plate: n nodal circles.

    W(R) = J0(lam R) - J1(lam)/I1(lam) I0(lam R), with lam the n-th root of the free-edge
    moment condition -J0 - J1 I0/I1 + 2 (1 - nu) J1 / lam = 0 (zero shear is built into W).
    """

    def __init__(self, n: int = 2, poisson_ratio: float = 0.3) -> None:
        if not isinstance(n, (int, np.integer)) or not 1 <= n <= MAX_NODAL_CIRCLES:
            raise InvalidParameterError("n", n, f"a whole number in [1, {MAX_NODAL_CIRCLES}] (the count of nodal "
                                        "circles; more are not resolved by the film's radial grid)")
        if not 0.0 <= poisson_ratio < 0.5:
            raise InvalidParameterError("poisson_ratio", poisson_ratio, "in [0, 0.5)")
        self.n, self.poisson_ratio = int(n), float(poisson_ratio)
        self.name = f"plate:{self.n}"
        self.wavenumber = self._root(self.n, self.poisson_ratio)
        self._bessel_ratio = scipy.special.j1(self.wavenumber) / scipy.special.i1(self.wavenumber)

    @staticmethod
    def _root(n: int, nu: float) -> float:
        def moment(lam):
            return (-scipy.special.j0(lam) - scipy.special.j1(lam) * scipy.special.i0(lam) / scipy.special.i1(lam)
                    + 2 * (1 - nu) * scipy.special.j1(lam) / lam)

        grid = np.linspace(0.5, 4.0 * n + 6.0, 400 * n + 400)
        values = moment(grid)
        roots = [scipy.optimize.brentq(moment, a, b)
                 for a, b, fa, fb in zip(grid, grid[1:], values, values[1:]) if fa * fb < 0]
        return float(roots[n - 1])

    def _raw(self, R):
        lam = self.wavenumber
        return scipy.special.j0(lam * R) - self._bessel_ratio * scipy.special.i0(lam * R)

    def _raw_slope(self, R):
        lam = self.wavenumber
        return -lam * scipy.special.j1(lam * R) - self._bessel_ratio * lam * scipy.special.i1(lam * R)


class TabulatedShape(ExcitationShape):
    """A measured shape: (R, eps_hat) pairs, e.g. a vibrometer scan, interpolated by a cubic spline.

    The spline has zero slope at the axis (axisymmetry); the table must cover R = 0 to 1.
    Any amplitude scale is fine: the shape is normalised here.
    """

    def __init__(self, radius, values, name: str = "table") -> None:
        radius, values = np.asarray(radius, dtype=float), np.asarray(values, dtype=float)
        if radius.ndim != 1 or radius.shape != values.shape or radius.size < 4:
            raise DataFormatError(f"a tabulated shape needs >= 4 (R, eps_hat) pairs, got shapes {radius.shape} "
                                  f"and {values.shape}")
        if not (np.all(np.isfinite(radius)) and np.all(np.isfinite(values))):
            raise DataFormatError("a tabulated shape contains NaN or infinite values")
        if np.any(np.diff(radius) <= 0):
            raise DataFormatError("R must increase strictly down the table")
        if abs(radius[0]) > 1e-9 or abs(radius[-1] - 1.0) > 1e-9:
            raise DataFormatError("R must run from 0 to 1 (normalised radius r/r0); "
                                  f"got {radius[0]:g} to {radius[-1]:g}")
        if not np.any(values):
            raise DataFormatError("a tabulated shape cannot be zero everywhere")
        self.name = name
        self._spline = scipy.interpolate.CubicSpline(radius, values, bc_type=((1, 0.0), "not-a-knot"))
        self._derivative = self._spline.derivative()

    @classmethod
    def from_csv(cls, path: str | os.PathLike) -> "TabulatedShape":
        """Read a CSV of two columns, R and eps_hat (header optional, ``#`` comments allowed)."""
        names, table = read_numeric_csv(path)
        if table.shape[1] != 2:
            raise DataFormatError(f"{path}: a shape file has two columns (R, eps_hat), found {table.shape[1]}: {names}")
        return cls(table[:, 0], table[:, 1], name=os.fspath(path))

    def _raw(self, R):
        return self._spline(R)

    def _raw_slope(self, R):
        return self._derivative(R)


def paper_shape() -> TabulatedShape:
    """The stand-in for the paper's measured form of Fig. 3 (shipped with the package)."""
    with resources.as_file(_DATA / PAPER_SHAPE_FILE) as path:
        shape = TabulatedShape.from_csv(path)
    shape.name = "paper (Fig. 3 stand-in)"
    return shape


def parse_shape(spec: str) -> ExcitationShape:
    """A shape from its command-line form: ``piston``, ``plate:N``, ``paper`` or a CSV path."""
    if spec == "piston":
        return PistonShape()
    if spec == "paper":
        return paper_shape()
    if spec.startswith("plate:"):
        try:
            n = int(spec.split(":", 1)[1])
        except ValueError:
            raise InvalidParameterError("shape", spec, "plate:N with N a whole number >= 1") from None
        return PlateModeShape(n)
    if os.path.exists(spec):
        return TabulatedShape.from_csv(spec)
    raise InvalidParameterError("shape", spec, "piston, paper, plate:N, or the path of an existing CSV file")
