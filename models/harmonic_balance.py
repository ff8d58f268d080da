"""The periodic film by harmonic balance: the fixed-object film of eqs. (3), (5), (8) solved directly
for its periodic steady state, with no marching through excitation periods.

The film over a fixed object (gap H = 1 - delta eps_hat(R) sin T, eq. 8) is periodic in the fast time
T once settled. Instead of marching to that state (:mod:`nfal.models.reynolds`), we collocate in T:
M = 2 h + 1 equispaced phases T_k = 2 pi k / M carry the unknown gauge pressures u = P - 1 at every
non-rim node, d/dT is the Fourier (spectral) differentiation matrix of those phases, and Newton
solves the whole space-time system at once. The radial scheme is exactly the finite volumes of
:mod:`nfal.models.reynolds` (same faces, fluxes and BCs 5):

    V_n D[P_n H_n](T_k) = (F_{n+1/2}(T_k) - F_{n-1/2}(T_k)) / sigma,   F = R H^3 (P_{n+1}^2 - P_n^2) / (2 dR),

so as M grows the result converges (exponentially: the solution is smooth in T) to the time-marching
solution with dT -> 0. The Jacobian is block tridiagonal in R with dense M x M blocks; it is
stored in LAPACK band form (bandwidth M) and solved by banded LU. Newton starts from the perturbation solution
(first harmonic, eq. 10, plus Pi_5 of eq. 11), so 3-5 iterations reach round-off.

K(sigma, delta) = 2 <sum_n V_n u_n> / delta^2 is the calibration value of eq. (12) at finite delta.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy

from nfal.errors import ConvergenceError, InvalidParameterError

from .excitation import ExcitationShape, largest_excursion
from .perturbation import as_squeeze_numbers, radial_grid
from .reynolds import perturbation_film

#: Default harmonics h (M = 2 h + 1 collocation phases): K within ~1e-7 of the M -> infinity limit up to
#: delta = 0.3 (tests/test_harmonic_balance.py).
DEFAULT_HARMONICS = 8
#: Newton stops when the largest update of P - 1 is below this times delta^2 (K is O(delta^2)), plus 1e-15.
NEWTON_TOLERANCE = 1e-11
NEWTON_MAX_ITERATIONS = 20


def fourier_differentiation(points: int) -> np.ndarray:
    """The spectral d/dT matrix on ``points`` (odd) equispaced phases of one period 2 pi.

    D[k, j] = (-1)^(k - j) / (2 sin((k - j) pi / points)) for k != j, 0 on the diagonal (Trefethen,
    *Spectral Methods in MATLAB*, ch. 3, odd N).
    """
    index = np.arange(points)
    gap = index[:, None] - index[None, :]
    with np.errstate(divide="ignore"):
        matrix = (-1.0) ** gap / (2.0 * np.sin(gap * np.pi / points))
    np.fill_diagonal(matrix, 0.0)
    return matrix


@dataclasses.dataclass(frozen=True)
class HarmonicFilm:
    """The periodic film at one (sigma, delta) from :class:`HarmonicBalanceFilm`.

    Attributes
    ----------
    K : float
        Calibration value of eq. (12) at this finite delta.
    phases : ndarray
        Collocation phases T_k, (M,).
    pressure : ndarray
        P(R_n, T_k), (nodes, M).
    iterations : int
        Newton iterations taken.
    """

    K: float
    phases: np.ndarray
    pressure: np.ndarray
    iterations: int


class HarmonicBalanceFilm:
    """Periodic steady state of the fixed-object film, eqs. (3), (5), (8), by time collocation + Newton.

    Parameters
    ----------
    shape : ExcitationShape
        Excitation form eps_hat(R) (eq. 7).
    nodes : int
        Radial nodes of :func:`~nfal.models.perturbation.radial_grid` (>= 5).
    harmonics : int
        Harmonics h kept in T (>= 1); M = 2 h + 1 collocation phases.
    """

    def __init__(self, shape: ExcitationShape, nodes: int = 101, harmonics: int = DEFAULT_HARMONICS) -> None:
        if isinstance(harmonics, bool) or not isinstance(harmonics, (int, np.integer)) or harmonics < 1:
            raise InvalidParameterError("harmonics", harmonics, "a whole number >= 1")
        self.shape, self.harmonics = shape, int(harmonics)
        self.R, self._faces, self.volumes = radial_grid(nodes)
        self.nodes = self.R.size
        self.points = 2 * self.harmonics + 1
        self.phases = 2.0 * np.pi * np.arange(self.points) / self.points
        self._eps_nodes = shape(self.R)
        self._eps_faces = shape(self._faces)
        self._conductance = self._faces / self.R[1]
        self.largest_eps = largest_excursion(self._eps_nodes, self._eps_faces)
        self._assemble_pattern()

    def _assemble_pattern(self) -> None:
        """Row/column indices of the Jacobian's non-zeros (unknown (n, k) is n M + k)."""
        m, M = self.nodes - 1, self.points
        self._D = fourier_differentiation(M)
        node = np.arange(m)
        # dense time blocks on the block diagonal
        block_rows = (node[:, None, None] * M + np.arange(M)[None, :, None]) * np.ones((1, 1, M), dtype=int)
        block_cols = (node[:, None, None] * M + np.arange(M)[None, None, :]) * np.ones((1, M, 1), dtype=int)
        # radial couplings (same phase) to the nodes below and above
        lower = (np.arange(1, m)[:, None] * M + np.arange(M)).ravel()
        upper = (np.arange(m - 1)[:, None] * M + np.arange(M)).ravel()
        rows = np.concatenate((block_rows.ravel(), lower, upper))
        self._cols = np.concatenate((block_cols.ravel(), lower - M, upper + M))
        self._band_rows = M + rows - self._cols  # LAPACK band storage: ab[M + i - j, j] = J[i, j]
        self._size = m * M

    def initial_guess(self, sigma: float, delta: float) -> np.ndarray:
        """Perturbation solution delta Re(Pi e^{iT}) + delta^2 Pi_5 at the phases, (nodes, M)."""
        return perturbation_film(self.shape, sigma, delta, self.R, self._faces, self.phases)

    def solve(self, sigma: float, delta: float, guess: np.ndarray | None = None, motion: complex = 0.0) -> HarmonicFilm:
        """The periodic film at squeeze number ``sigma`` (eq. 2) and excitation norm ``delta`` (eq. 7).

        ``guess`` (nodes x M gauge pressures, e.g. a neighbouring solution) replaces the perturbation start.
        ``motion`` zeta is the object's own fast oscillation, z = hbar (1 + Im(zeta e^{iT})) (eq. 1): the gap
        becomes H = 1 - delta eps_hat sin T + Im(zeta e^{iT}) (0: the fixed object of eq. 8).

        Raises
        ------
        InvalidParameterError
            On a bad sigma or delta (the gap must stay open: delta max eps_hat < 1).
        ConvergenceError
            When Newton does not converge.
        """
        sigmas = as_squeeze_numbers(sigma)
        if sigmas.size != 1:
            raise InvalidParameterError("sigma", sigma, "one finite squeeze number > 0")
        sigma = float(sigmas[0])
        delta = float(delta)
        if not (np.isfinite(delta) and 0.0 < delta and delta * self.largest_eps < 1.0):
            raise InvalidParameterError("delta", delta,
                                        f"a number with 0 < delta < 1 / max |eps_hat| = {1.0 / self.largest_eps:.4g}")
        u = self.initial_guess(sigma, delta) if guess is None else np.array(guess, dtype=float)
        u[-1] = 0.0
        sine = np.sin(self.phases)
        rigid = 1.0 + np.imag(complex(motion) * np.exp(1j * self.phases))[None, :]
        h_nodes = rigid - delta * self._eps_nodes[:, None] * sine[None, :]
        c_faces = self._conductance[:, None] * (rigid - delta * self._eps_faces[:, None] * sine[None, :]) ** 3 / sigma
        tolerance = NEWTON_TOLERANCE * delta**2 + 1e-15  # the floor: round-off in the residual
        for iteration in range(1, NEWTON_MAX_ITERATIONS + 1):
            residual, jacobian = self._residual_jacobian(u, h_nodes, c_faces)
            step = scipy.linalg.solve_banded((self.points, self.points), jacobian, -residual.ravel(),
                                       overwrite_ab=True, check_finite=False).reshape(residual.shape)
            u[:-1] += step
            if not np.all(np.isfinite(u)):
                break
            if np.max(np.abs(step)) <= tolerance:
                K = 2.0 * float(np.sum(self.volumes[:, None] * u) / self.points) / delta**2
                return HarmonicFilm(K, self.phases, 1.0 + u, iteration)
        raise ConvergenceError(f"harmonic balance did not converge (sigma = {sigma:g}, delta = {delta:g}, "
                               f"{self.harmonics} harmonics)")

    def _residual_jacobian(self, u: np.ndarray, h_nodes: np.ndarray, c_faces: np.ndarray):
        """Residual V D[P H] - (flux jump) / sigma on the non-rim nodes, (m, M), and its Jacobian (band form)."""
        m, M, volumes = self.nodes - 1, self.points, self.volumes[:-1, None]
        flux = 0.5 * c_faces * (u[1:] - u[:-1]) * (2.0 + u[1:] + u[:-1])  # (faces, M), already / sigma
        flux_below = np.vstack((np.zeros((1, M)), flux[:-1]))
        mass = u[:-1] * h_nodes[:-1] + h_nodes[:-1] - 1.0
        residual = volumes * (mass @ self._D.T) - (flux[:m] - flux_below)
        one_u = 1.0 + u
        c_below = np.vstack((np.zeros((1, M)), c_faces[:m - 1]))
        blocks = volumes[:, :, None] * self._D[None, :, :] * h_nodes[:-1, None, :]
        blocks[:, np.arange(M), np.arange(M)] += (c_faces[:m] + c_below) * one_u[:-1]
        lower = -c_faces[:m - 1] * one_u[:m - 1]  # row n + 1, column n
        upper = -c_faces[:m - 1] * one_u[1:m]     # row n, column n + 1
        values = np.concatenate((blocks.ravel(), lower.ravel(), upper.ravel()))
        band = np.zeros((2 * M + 1, self._size))
        band[self._band_rows, self._cols] = values
        return residual, band

    def K(self, sigma: float, delta: float, motion: complex = 0.0) -> float:
        """K(sigma, delta) of eq. (12) (see :meth:`solve`)."""
        return self.solve(sigma, delta, motion=motion).K
