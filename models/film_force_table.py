"""A table of the periodic film force K(sigma, delta) for one excitation form, by harmonic balance.

(With a rig, for the free object: its own fast oscillation is part of the gap; see ``rig`` below.)

The period-averaged force of the film over an object at clearance hbar under |a| is
pi r0^2 p_a delta^2 K(sigma, delta) (eq. 12), with sigma(hbar) of eq. (2) and delta = |a| / hbar. K
depends on delta only through delta^2 (delta -> -delta is the shift T -> T + pi), smoothly: so per
squeeze number the table keeps K as a polynomial in delta^2 through ``DELTA_POINTS`` harmonic-balance
solutions (:mod:`nfal.models.harmonic_balance`) at Chebyshev points in delta^2, and its coefficients are
interpolated by a cubic spline in log sigma. Building it costs ``sigmas`` x ``DELTA_POINTS`` Newton solves, once
per shape and grid; :meth:`FilmForceTable.check` measures its interpolation error against direct solves between
the table points.

Outside the table (sigma beyond ``sigma_range``, delta beyond ``delta_max``) K is held at the
nearest edge; the plant only goes there at touchdown and lift-off.
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import math
import os

import numpy as np
import scipy

from nfal.errors import InvalidParameterError

from . import piecewise, slow_kernels
from .disk_cache import cached_array
from .excitation import ExcitationShape, PistonShape
from .harmonic_balance import HarmonicBalanceFilm
from .perturbation import first_order_pressure
from .rig import RigParameters


logger = logging.getLogger(__name__)

#: Table points in delta per squeeze number: Chebyshev-Gauss points in delta^2 over [0, delta_max^2].
DELTA_POINTS = 6
DEFAULT_SIGMA_RANGE = (5.0, 5000.0)
DEFAULT_SIGMAS = 40
#: Default largest gap swing tabulated, delta_max max eps_hat (the gap closes at 1).
DEFAULT_GAP_SWING = 0.7


class FilmForceTable:
    """K(sigma, delta) of eq. (12) at finite delta, tabulated by harmonic balance for one shape.

    Parameters
    ----------
    shape : ExcitationShape
        Excitation form eps_hat(R) (eq. 7).
    nodes : int
        Radial nodes of the film (as :class:`~nfal.models.coupled.CoupledModel`).
    harmonics : int
        Harmonics of the harmonic balance.
    sigma_range : (float, float)
        Squeeze numbers tabulated (log-spaced).
    sigmas : int
        Table points in sigma (>= 4).
    delta_max : float, optional
        Largest excitation norm tabulated, 0 < delta_max max eps_hat < 1 (default: the gap swing
        delta_max max eps_hat = ``DEFAULT_GAP_SWING``).
    rig : RigParameters, optional
        With a rig, the object is free: its own fast oscillation (first order in delta, from eq. 4 and the
        first-harmonic forces, :meth:`response`) is part of the gap the film sees, and K includes its
        O(C_s*) effect on the mean force (2e-3 of the clearance for a piston at 77 um). Without one (default),
        the fixed object of eq. (8). The rig's frequency fixes sigma -> hbar for that response.
    richardson : bool
        Tabulate the Richardson extrapolation (4 K_fine - K) / 3 of ``nodes`` and 2 ``nodes`` - 1 radial
        nodes (the scheme is second order in dR) instead of K on ``nodes`` alone.
    values : ndarray, optional
        K at the table's (sigma, delta) points as a table with the same settings computed them (``values``
        of that table, e.g. from :func:`cached_table`): the solves are skipped.
    """

    def __init__(self, shape: ExcitationShape, nodes: int = 41, harmonics: int = 6,
                 sigma_range: tuple[float, float] = DEFAULT_SIGMA_RANGE, sigmas: int = DEFAULT_SIGMAS,
                 delta_max: float | None = None, rig: RigParameters | None = None, richardson: bool = True,
                 values: np.ndarray | None = None) -> None:
        low, high = (float(value) for value in sigma_range)
        if not 0.0 < low < high < np.inf:
            raise InvalidParameterError("sigma_range", sigma_range, "two finite squeeze numbers 0 < low < high")
        if isinstance(sigmas, bool) or not isinstance(sigmas, (int, np.integer)) or sigmas < 4:
            raise InvalidParameterError("sigmas", sigmas, "a whole number >= 4")
        self.film = HarmonicBalanceFilm(shape, nodes, harmonics)
        self.fine_film = HarmonicBalanceFilm(shape, 2 * nodes - 1, harmonics) if richardson else None
        if delta_max is None:
            delta_max = DEFAULT_GAP_SWING / self.film.largest_eps
        if not 0.0 < float(delta_max) < 1.0 / self.film.largest_eps:
            raise InvalidParameterError("delta_max", delta_max, f"a number in (0, {1.0 / self.film.largest_eps:.4g})")
        self.sigma_range, self.delta_max = (low, high), float(delta_max)
        self.sigmas = np.geomspace(low, high, int(sigmas))
        chebyshev = np.cos((2 * np.arange(DELTA_POINTS) + 1) * np.pi / (2 * DELTA_POINTS))
        self.deltas = self.delta_max * np.sqrt((1.0 - chebyshev[::-1]) / 2.0)
        self.rig = rig
        self._harmonic_spline = scipy.interpolate.CubicSpline(np.log(self.sigmas), self._first_harmonics())
        if values is None:
            values = self._solve_all(self.film)
            if self.fine_film is not None:
                values = (4.0 * self._solve_all(self.fine_film) - values) / 3.0
        elif np.shape(values) != (self.sigmas.size, self.deltas.size):
            raise InvalidParameterError("values", np.shape(values), f"a {self.sigmas.size} x {self.deltas.size} table")
        self.values = np.asarray(values, dtype=float)
        powers = np.vander(self.deltas**2, self.deltas.size, increasing=True)
        coefficients = np.linalg.solve(powers, self.values.T).T  # K = sum_p c_p delta^(2p)
        self._spline = scipy.interpolate.CubicSpline(np.log(self.sigmas), coefficients)
        #: the same spline as arrays for compiled code (:mod:`nfal.models.piecewise`): breaks in log sigma, and per
        #: interval, power of delta^2 and cubic coefficient (highest first)
        self.breaks = np.ascontiguousarray(self._spline.x)
        self.pieces = np.ascontiguousarray(self._spline.c.transpose(1, 2, 0))
        self._curve = piecewise.curve(True, self.breaks, self.pieces, low, high, self.delta_max)

    def _solve_all(self, film: HarmonicBalanceFilm) -> np.ndarray:
        """K at every (sigma, delta) of the table on ``film``'s grid."""
        values = np.empty((self.sigmas.size, self.deltas.size))
        for j, delta in enumerate(self.deltas):
            guess = None
            for i, sigma in enumerate(self.sigmas):  # continuation in sigma: Newton starts next door
                solution = film.solve(sigma, delta, guess, delta * self.response(sigma))
                values[i, j], guess = solution.K, solution.pressure - 1.0
        return values

    def _first_harmonics(self) -> np.ndarray:
        """[Re S, Im S, Re Q, Im Q] per table sigma: S = 2 sum V Pi of the shape, Q the same for eps_hat = 1."""
        film, piston = self.film, PistonShape()
        rows = []
        for sigma in self.sigmas:
            S = 2.0 * np.sum(film.volumes * first_order_pressure(film.shape, sigma, film.nodes)[1])
            Q = 2.0 * np.sum(film.volumes * first_order_pressure(piston, sigma, film.nodes)[1])
            rows.append((S.real, S.imag, Q.real, Q.imag))
        return np.array(rows)

    def first_harmonic_forces(self, sigma: float) -> tuple[complex, complex]:
        """(S, Q): the first-harmonic film force per unit delta, 2 sum V Pi (eq. 10), for the excitation form
        (S) and for a rigid motion of the object (Q, eps_hat = 1), interpolated in log sigma."""
        values = self._harmonic_spline(math.log(min(max(sigma, self.sigma_range[0]), self.sigma_range[1])))
        return complex(values[0], values[1]), complex(values[2], values[3])

    def response(self, sigma: float) -> complex:
        """zeta / delta: the free object's fast oscillation per unit delta, z = hbar (1 + Im(zeta e^{iT})).

        The surface drives the film with S, the object moving by zeta drives it like a piston with -zeta Q
        (:meth:`first_harmonic_forces`); eq. (4) at the first harmonic, -Z zeta = i C (delta S - zeta Q) with
        C = C_s* and Z = hbar / h0 of eq. (14), gives zeta = i C delta S / (i C Q - Z). 0 without a rig.
        """
        if self.rig is None:
            return 0.0j
        S, Q = self.first_harmonic_forces(sigma)
        C, Z = self.rig.stiffness_coefficient, float(self.rig.clearance_at(sigma)) / self.rig.reference_clearance
        return 1j * C * S / (1j * C * Q - Z)

    def direct(self, sigma: float, delta: float) -> float:
        """K(sigma, delta) solved directly (with the table's Richardson extrapolation, if any)."""
        motion = delta * self.response(sigma)
        coarse = self.film.K(sigma, delta, motion)
        return coarse if self.fine_film is None else (4.0 * self.fine_film.K(sigma, delta, motion) - coarse) / 3.0

    def __call__(self, sigma, delta):
        """K(sigma, delta) (broadcast), held at the table's edges outside it."""
        log_sigma = np.log(np.clip(np.asarray(sigma, dtype=float), *self.sigma_range))
        squared = np.minimum(np.abs(np.asarray(delta, dtype=float)), self.delta_max) ** 2
        c = self._spline(log_sigma)
        value = c[..., -1]
        for power in range(DELTA_POINTS - 2, -1, -1):  # Horner in delta^2
            value = c[..., power] + squared * value
        return value

    def curve(self) -> tuple:
        """K(sigma, delta) as the piecewise polynomial of compiled code (:mod:`nfal.models.slow_kernels`)."""
        return self._curve

    def scalar(self, sigma: float, delta: float) -> float:
        """:meth:`__call__` for one (sigma, delta), compiled (~30x faster than the array path)."""
        return slow_kernels.curve_value(*self._curve, sigma, delta)

    def check(self, points: int = 6) -> float:
        """Largest |K_table - K_direct| over ``points`` sigmas midway between table points, at delta
        midway between the table's (and at delta_max / 10): the interpolation error, measured."""
        middles = np.sqrt(self.sigmas[:-1] * self.sigmas[1:])
        chosen = middles[np.linspace(0, middles.size - 1, points).astype(int)]
        deltas = np.concatenate(([0.1 * self.delta_max], 0.5 * (self.deltas[:-1] + self.deltas[1:])))
        return max(abs(float(self(sigma, delta)) - self.direct(sigma, delta)) for sigma in chosen for delta in deltas)


#: Bump when the table's numbers would change for the same settings (the scheme, the δ points, ...).
CACHE_FORMAT = 1


def cache_key(shape: ExcitationShape, **settings) -> str:
    """A digest of everything a table's values depend on: the shape (sampled finely), the settings, the
    format. ``rig`` enters through its fields."""
    digest = hashlib.sha256(f"film-force-table {CACHE_FORMAT}".encode())
    digest.update(np.ascontiguousarray(shape(np.linspace(0.0, 1.0, 2001)), dtype=float).tobytes())
    for name, value in sorted(settings.items()):
        value = dataclasses.astuple(value) if dataclasses.is_dataclass(value) else value
        digest.update(f"{name}={value!r};".encode())
    return digest.hexdigest()[:32]


def cached_table(shape: ExcitationShape, cache_dir: str | os.PathLike | None = None, **settings) -> FilmForceTable:
    """:class:`FilmForceTable` (``settings`` its keyword arguments), its values kept in ``cache_dir``
    (default ``$NFAL_CACHE_DIR`` or ``~/.cache/nfal``, folder ``film_tables``) so that a second build with
    the same shape and settings skips the solves (:func:`~nfal.models.disk_cache.cached_array`)."""
    table = {}  # the one table built: from the stored values (the check) or by the solves

    def solve() -> np.ndarray:
        table["built"] = FilmForceTable(shape, **settings)
        return table["built"].values

    def load(stored: np.ndarray) -> None:
        table["built"] = FilmForceTable(shape, **settings, values=stored)

    cached_array("film_tables", cache_key(shape, **settings), solve, cache_dir, check=load)
    return table["built"]
