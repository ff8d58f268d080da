"""K(sigma) by time marching Reynolds' equation over a FIXED object (Sec. 3.2.1, eqs. 3, 5, 8, 12).

The object sits at the constant clearance hbar; the gap is H / hbar = 1 - delta eps_hat(R) sin T
(eq. 8) and, with sigma the squeeze number of eq. (2), Reynolds' equation (3) reads

    d/dR (R H^3 P dP/dR) = sigma R d(P H)/dT,      dP/dR(0) = 0,  P(1) = 1      (BCs 5).

Discretisation (chosen so that its delta -> 0 limit is the finite-volume problem that
:func:`nfal.models.perturbation.first_order_pressure` solves):

* conservative, node-centred finite volumes on :func:`~nfal.models.perturbation.radial_grid`;
  per node the gauge pressure u = P - 1 (unknown; held at 0 on the rim) and the mass P H;
* face flux F_{n+1/2} = R_{n+1/2} H_{n+1/2}^3 (P_{n+1}^2 - P_n^2) / (2 dR), H at the face radius,
  written (u_{n+1} - u_n)(2 + u_{n+1} + u_n) / 2 to avoid cancellation;
* V_n d(P_n H_n)/dT = (F_{n+1/2} - F_{n-1/2}) / sigma, no flux through the axis;
* BDF2 in time (L-stable, second order), Newton per step with the exact tridiagonal Jacobian,
  solved by the Thomas algorithm; all inside ``numba.njit(cache=True)`` kernels.

The run starts from the perturbation solution (first harmonic, eq. 10, plus the discrete mean
correction Pi_5 of eq. 11) and marches whole periods to the periodic steady state. Near it the
period map contracts each slow film mode by exp(-2 pi lambda_j / sigma) per period (lambda_1 =
5.78 for the axis-to-rim diffusion), i.e. slowly for sigma in the hundreds. We accelerate with a
vector Aitken (one-mode reduced-rank) extrapolation on the period map: from three consecutive
period-boundary states S0, S1, S2 the contraction ratio r = <D2, D1> / <D1, D1> (D = successive
differences) is estimated and, when the difference is dominated by one mode, the state jumps to
S2 + D2 r / (1 - r). K is declared converged when the geometric model of the remaining change,
|K_2 - K_1| max(1, r / (1 - r)), is below ``tolerance`` times max(|K|, 0.01).

The period average of the gauge pressure gives the levitation force of eq. (12):
F / (p_a r0^2) = 2 pi <int_0^1 R (P - 1) dR> = pi delta^2 K, i.e. K = 2 <sum_n V_n u_n> / delta^2.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Callable

import numba
import numpy as np
import scipy

from nfal.errors import ConvergenceError, InvalidParameterError

from . import numba_cache
from .excitation import ExcitationShape, largest_excursion
from .film_kernel import face_fluxes, flux_jacobian, thomas_solve
from .perturbation import as_squeeze_numbers, first_order_pressure, radial_grid

numba_cache.install()  # before the kernels below: their compiled code outlives an FMU's temporary folder

logger = logging.getLogger(__name__)

#: Files whose kernels the kernels here call (the compiled cache's key includes them: numba_cache).
KERNEL_DEPENDENCIES = ("film_kernel.py",)

#: Newton stops when the largest pressure update is below this times delta^2 (K is O(delta^2)).
NEWTON_TOLERANCE = 1e-10
NEWTON_MAX_ITERATIONS = 30
DEFAULT_MAX_PERIODS = 2000
#: Periods per reduced-rank extrapolation cycle.
EXTRAPOLATION_CYCLE = 8
#: K values of magnitude below this are converged in absolute rather than relative terms.
K_SCALE_FLOOR = 1e-2


# --------------------------------------------------------------------------------------------------
# numba kernels
# --------------------------------------------------------------------------------------------------
@numba.njit(cache=True)
def _march_fixed_film(u_now, u_prev, eps_nodes, eps_faces, conductance, volumes, sigma, delta,
                      steps, record):
    """March one excitation period of the fixed-object film with BDF2 + Newton.

    ``u_now`` (T = 0) and ``u_prev`` (T = -dT) are the gauge pressures P - 1 on all nodes; both are
    overwritten with the levels at T = 2 pi and 2 pi - dT. ``conductance[f]`` = R_f / dR for face f (the film's
    kernels: :mod:`nfal.models.film_kernel`).
    ``record`` (steps x nodes) receives u after every step. Returns (sum over steps of
    sum_n V_n u_n, status): status 0 = fine, 1 = Newton failed, 2 = gap closed.
    """
    nodes = u_now.shape[0]
    m = nodes - 1  # unknowns: every node but the rim
    dt = 2.0 * np.pi / steps
    tol = NEWTON_TOLERANCE * delta * delta
    lower = np.empty(m)
    diag = np.empty(m)
    upper = np.empty(m)
    res = np.empty(m)
    du = np.empty(m)
    work = np.empty(2 * m)  # the factorisation: modified upper diagonal and reciprocal pivots
    hist = np.empty(m)
    h_nodes = np.empty(nodes)
    c_faces = np.empty(nodes - 1)
    u = np.empty(nodes)
    flux = np.empty(nodes - 1)
    force_sum = 0.0
    for j in range(steps):
        # masses (P H - 1) at the two previous levels
        s_now = np.sin(j * dt)
        s_prev = np.sin((j - 1) * dt)
        for n in range(m):
            h_now = 1.0 - delta * eps_nodes[n] * s_now
            h_prev = 1.0 - delta * eps_nodes[n] * s_prev
            mass_now = u_now[n] * h_now + (h_now - 1.0)
            mass_prev = u_prev[n] * h_prev + (h_prev - 1.0)
            hist[n] = -4.0 * mass_now + mass_prev
        s = np.sin((j + 1) * dt)
        for n in range(nodes):
            h_nodes[n] = 1.0 - delta * eps_nodes[n] * s
            if h_nodes[n] <= 0.0:
                return force_sum, 2
        for f in range(nodes - 1):
            hf = 1.0 - delta * eps_faces[f] * s
            if hf <= 0.0:
                return force_sum, 2
            c_faces[f] = conductance[f] * hf * hf * hf / sigma
        for n in range(nodes):
            u[n] = 2.0 * u_now[n] - u_prev[n]
        u[nodes - 1] = 0.0
        converged = False
        for _ in range(NEWTON_MAX_ITERATIONS):
            face_fluxes(u, c_faces, flux, nodes - 1)
            flux_jacobian(u, c_faces, lower, diag, upper)
            for n in range(m):
                mass = u[n] * h_nodes[n] + (h_nodes[n] - 1.0)
                net = flux[n] - (flux[n - 1] if n > 0 else 0.0)
                res[n] = -(volumes[n] * (3.0 * mass + hist[n]) / (2.0 * dt) - net)
                diag[n] += 3.0 * volumes[n] * h_nodes[n] / (2.0 * dt)
            thomas_solve(lower, diag, upper, res, du, work)
            largest = 0.0
            for n in range(m):
                u[n] += du[n]
                if abs(du[n]) > largest:
                    largest = abs(du[n])
            if largest <= tol:
                converged = True
                break
        if not converged:
            return force_sum, 1
        total = 0.0
        for n in range(nodes):
            u_prev[n] = u_now[n]
            u_now[n] = u[n]
            record[j, n] = u[n]
            total += volumes[n] * u[n]
        force_sum += total
    return force_sum, 0


# --------------------------------------------------------------------------------------------------
# Python layer
# --------------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class PeriodicFilm:
    """The periodic steady state of the fixed-object film at one squeeze number.

    Attributes
    ----------
    sigma, delta : float
        Squeeze number (eq. 2) and excitation norm (eq. 7).
    K : float
        Calibration value of eq. (12) from the last marched period.
    R : ndarray
        Radial nodes.
    time : ndarray
        Phases T of the stored pressure levels, (steps_per_period,), in (0, 2 pi].
    pressure : ndarray
        P(R, T) over the last period, (steps_per_period, nodes).
    periods : int
        Excitation periods marched (extrapolation jumps not counted).
    extrapolations : int
        Vector-Aitken jumps taken.
    change_estimate : float
        The geometric model's estimate of |K_final - K| (absolute).
    """

    sigma: float
    delta: float
    K: float
    R: np.ndarray
    time: np.ndarray
    pressure: np.ndarray
    periods: int
    extrapolations: int
    change_estimate: float


#: Grid ceilings: 2001 nodes and 8192 steps per period resolve any film of the paper far past convergence
#: (its results use 101 and 256); beyond them a run only costs memory and hours.
MAX_NODES, MAX_STEPS_PER_PERIOD = 2001, 8192


def check_grid(nodes, steps_per_period, names: tuple[str, str] = ("nodes", "steps_per_period")) -> None:
    """Raise :class:`InvalidParameterError` (naming the value by ``names``) unless ``nodes`` is in [5, MAX_NODES]
    and ``steps_per_period`` in [8, MAX_STEPS_PER_PERIOD] (whole numbers)."""
    for name, value, low, high in ((names[0], nodes, 5, MAX_NODES), (names[1], steps_per_period, 8,
                                                                     MAX_STEPS_PER_PERIOD)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not low <= value <= high:
            raise InvalidParameterError(name, value, f"a whole number in [{low}, {high}]")


def _check_settings(delta, nodes, steps_per_period, tolerance, max_periods) -> tuple[float, int, int, float, int]:
    try:
        delta_value = float(delta)
    except (TypeError, ValueError):
        raise InvalidParameterError("delta", delta, "a number with 0 < delta < 1") from None
    if not 0.0 < delta_value < 1.0:
        raise InvalidParameterError("delta", delta, "a number with 0 < delta < 1")
    check_grid(nodes, steps_per_period)
    try:
        tol = float(tolerance)
    except (TypeError, ValueError):
        raise InvalidParameterError("tolerance", tolerance, "a number in (0, 0.1]") from None
    if not 0.0 < tol <= 0.1:
        raise InvalidParameterError("tolerance", tolerance, "a number in (0, 0.1]")
    if isinstance(max_periods, bool) or not isinstance(max_periods, (int, np.integer)) or max_periods < 3:
        raise InvalidParameterError("max_periods", max_periods, "a whole number >= 3")
    return delta_value, int(nodes), int(steps_per_period), tol, int(max_periods)


def discrete_mean_correction(shape: ExcitationShape, amplitude: np.ndarray, R: np.ndarray,
                             faces: np.ndarray) -> np.ndarray:
    """Pi_5 of eq. (11) for this finite-volume scheme, from the first-order amplitude Pi.

    The period average of the face flux vanishes, which at O(delta^2) gives per face
    Delta Pi_5 = -Delta |Pi|^2 / 4 + (3/2) eps_hat(R_face) Delta Pi_2, with Pi_5(1) = 0.
    """
    pi_2 = -amplitude.imag
    jumps = -np.diff(np.abs(amplitude) ** 2) / 4.0 + 1.5 * shape(faces) * np.diff(pi_2)
    mean = np.zeros(R.size)
    mean[:-1] = -np.cumsum(jumps[::-1])[::-1]
    return mean


def periodic_film(shape: ExcitationShape, sigma: float, delta: float = 0.01, nodes: int = 101,
                  steps_per_period: int = 256, tolerance: float = 1e-7,
                  max_periods: int = DEFAULT_MAX_PERIODS, extrapolate: bool = True) -> PeriodicFilm:
    """March the fixed-object film of eqs. (3), (5), (8) to its periodic steady state.

    Parameters
    ----------
    shape : ExcitationShape
        Excitation form eps_hat(R) (eq. 7).
    sigma : float
        Squeeze number (eq. 2), finite and > 0.
    delta : float
        Excitation norm delta of eq. (7), 0 < delta < 1.
    nodes : int
        Radial nodes (>= 5) of :func:`~nfal.models.perturbation.radial_grid`.
    steps_per_period : int
        BDF2 steps per excitation period (>= 8).
    tolerance : float
        Relative tolerance on K (with the floor max(|K|, 0.01)).
    max_periods : int
        Give up after this many periods.
    extrapolate : bool
        Use the vector-Aitken jumps on the period map (default); False marches plainly.

    Returns
    -------
    PeriodicFilm

    Raises
    ------
    InvalidParameterError
        On a bad argument.
    ConvergenceError
        When Newton fails, the gap closes, or K has not converged within ``max_periods``.
    """
    sigmas = as_squeeze_numbers(sigma)
    if sigmas.size != 1:
        raise InvalidParameterError("sigma", sigma, "one finite squeeze number > 0")
    sigma = float(sigmas[0])
    delta, nodes, steps, tol, max_periods = _check_settings(delta, nodes, steps_per_period, tolerance, max_periods)
    R, faces, volumes = radial_grid(nodes)
    eps_nodes, eps_faces, largest = _form_on_grid(shape, delta, R, faces)
    conductance = faces / R[1]
    dt = 2.0 * np.pi / steps
    u_now, u_prev = np.ascontiguousarray(perturbation_film(shape, sigma, delta, R, faces, (0.0, -dt)).T)
    record = np.empty((steps, nodes))
    scale_force = 2.0 / (steps * delta**2)

    slow_ratio = slowest_period_ratio(R, faces, volumes, sigma, delta * largest)
    factor = max(1.0, slow_ratio / (1.0 - slow_ratio))
    states = [np.concatenate((u_now, u_prev))]
    K_value, K_last, change, extrapolations = np.nan, np.nan, np.inf, 0
    previous_settled = False  # two successive settled periods are required
    for period in range(1, max_periods + 1):
        force_sum, status = _march_fixed_film(u_now, u_prev, eps_nodes, eps_faces, conductance, volumes,
                                              sigma, delta, steps, record)
        _check_march(status, sigma, delta)
        K_last, K_value = K_value, scale_force * force_sum
        if not np.isfinite(K_value):
            raise ConvergenceError(f"the film solution blew up (sigma = {sigma:g}, delta = {delta:g})")
        states.append(np.concatenate((u_now, u_prev)))
        if len(states) >= 3:  # two periods since the last start or jump
            change = abs(K_value - K_last) * factor
            settled = change <= tol * max(abs(K_value), K_SCALE_FLOOR)
            if settled and previous_settled:
                logger.debug("sigma %g: K = %.10g after %d periods, %d extrapolations", sigma, K_value, period,
                             extrapolations)
                return PeriodicFilm(sigma, delta, float(K_value), R, dt * np.arange(1, steps + 1), 1.0 + record,
                                    period, extrapolations, float(change))
            previous_settled = settled
        if extrapolate and len(states) == EXTRAPOLATION_CYCLE + 1:
            jumped = reduced_rank_extrapolation(np.array(states))
            u_now[:], u_prev[:] = jumped[:nodes], jumped[nodes:]
            states = [jumped]
            K_value, previous_settled = np.nan, False
            extrapolations += 1
        elif not extrapolate:
            states = states[-2:]
    raise ConvergenceError(f"K did not converge within {max_periods} periods (sigma = {sigma:g}, delta = {delta:g}): "
                           f"last K = {K_value:.8g}, estimated remaining change {change:.3g}")


def _form_on_grid(shape: ExcitationShape, delta: float, R: np.ndarray,
                  faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """eps_hat at the nodes and faces, and its largest excursion; refused if delta * eps_hat would close the gap."""
    eps_nodes = np.ascontiguousarray(shape(R), dtype=float)
    eps_faces = np.ascontiguousarray(shape(faces), dtype=float)
    largest = largest_excursion(eps_nodes, eps_faces)
    if delta * largest >= 1.0:
        raise InvalidParameterError("delta", delta, f"small enough that the gap stays open: delta * max |eps_hat| < 1 "
                                    f"(max |eps_hat| = {largest:.4g})")
    return eps_nodes, eps_faces, largest


def perturbation_film(shape: ExcitationShape, sigma: float, delta: float, R: np.ndarray, faces: np.ndarray,
                      phases) -> np.ndarray:
    """The perturbation solution P - 1 = delta Re(Pi e^{iT}) + delta^2 Pi_5 at the phases T, (nodes, phases): the
    start of a march (T = 0 and -dT, here and in the coupled model) and of harmonic balance (its phases)."""
    _, amplitude = first_order_pressure(shape, sigma, R.size)
    mean = discrete_mean_correction(shape, amplitude, R, faces)
    return delta * np.real(amplitude[:, None] * np.exp(1j * np.asarray(phases))[None, :]) + delta**2 * mean[:, None]


def _check_march(status: int, sigma: float, delta: float) -> None:
    """Raise for a period the march could not complete (status 1: Newton failed; 2: the gap closed)."""
    if status == 1:
        raise ConvergenceError(f"Newton did not converge in a time step (sigma = {sigma:g}, delta = {delta:g}); "
                               "try more steps_per_period")
    if status == 2:  # excluded by _form_on_grid; kept as a guard
        raise ConvergenceError(f"the gap closed (sigma = {sigma:g}, delta = {delta:g})")


def reduced_rank_extrapolation(states: np.ndarray) -> np.ndarray:
    """The fixed point of a (nearly linear) map estimated from iterates ``states[0..w]`` (RRE).

    With the differences D_i = S_{i+1} - S_i, choose weights g (sum 1) minimising |sum g_i D_i|
    and return sum g_i S_{i+1}. For a linear map with w slow modes this is exact (it is GMRES in
    disguise); faster modes have died out within the cycle anyway.
    """
    differences = np.diff(states, axis=0).T
    basis = differences[:, :-1] - differences[:, -1:]
    weights, *_ = np.linalg.lstsq(basis, -differences[:, -1], rcond=1e-12)
    weights = np.append(weights, 1.0 - weights.sum())
    return states[1:].T @ weights


#: lambda_1, the slowest decay rate of the film's axis-to-rim diffusion (closed axis, open rim: the first zero of
#: J0 squared, 2.405^2), to the two digits the step-size bounds use.
SLOWEST_FILM_EIGENVALUE = 5.78


def slowest_period_ratio(R: np.ndarray, faces: np.ndarray, volumes: np.ndarray, sigma: float,
                         gap_swing: float) -> float:
    """Contraction per period of the film's slowest mode, exp(-2 pi lambda_1 / sigma) (lambda_1 ~ 5.78).

    lambda_1 is the smallest eigenvalue of the finite-volume diffusion operator with a closed axis and
    an open rim; it is scaled by (1 - ``gap_swing``)^3, the least conductance the film can have, so
    that the ratio is an upper bound for finite delta.
    """
    conductance = faces[:-1] / R[1]  # faces between unknown nodes, then the rim face
    unknown = R.size - 1
    diag = np.concatenate(([0.0], conductance)) + faces / R[1]
    diag = diag[:unknown]
    scale = 1.0 / np.sqrt(volumes[:unknown])
    main = diag * scale**2
    off = -conductance[: unknown - 1] * scale[:-1] * scale[1:]
    smallest = float(scipy.linalg.eigvalsh_tridiagonal(main, off, select="i", select_range=(0, 0))[0])
    return float(np.exp(-2.0 * np.pi * smallest * (1.0 - gap_swing) ** 3 / sigma))


def time_marching_K(shape: ExcitationShape, sigma, delta: float = 0.01, nodes: int = 101,
                    steps_per_period: int = 256, tolerance: float = 1e-7, max_periods: int = DEFAULT_MAX_PERIODS,
                    progress: Callable[[int, int], None] | None = None) -> np.ndarray:
    """The calibration function K(sigma) of eq. (12) by time marching the fixed-object film.

    K = F_levitation / (pi delta^2) with F the period-averaged film force of eq. (12); see
    :func:`periodic_film` for the scheme. Tends to
    :func:`~nfal.models.perturbation.perturbation_K` as delta -> 0 (the difference is O(delta^2):
    the force is even in delta, since delta -> -delta is the shift T -> T + pi).

    Parameters
    ----------
    shape : ExcitationShape
        Excitation form eps_hat(R).
    sigma : float or array_like
        Squeeze number(s) of eq. (2), finite and > 0.
    delta : float
        Excitation norm of eq. (7), 0 < delta < 1.
    nodes : int
        Radial nodes (>= 5).
    steps_per_period : int
        BDF2 steps per excitation period (>= 8).
    tolerance : float
        Relative convergence tolerance on each K.
    max_periods : int
        Periods allowed per squeeze number before :class:`ConvergenceError`.
    progress : callable, optional
        ``progress(done, total)`` after each squeeze number.

    Returns
    -------
    ndarray
        K at each sigma (same length as ``sigma`` flattened to 1-D).
    """
    sigmas = as_squeeze_numbers(sigma)
    _check_settings(delta, nodes, steps_per_period, tolerance, max_periods)
    if progress is not None and not callable(progress):
        raise InvalidParameterError("progress", progress, "None or a callable(done, total)")
    values = np.empty_like(sigmas)
    for index, value in enumerate(sigmas):
        values[index] = periodic_film(shape, value, delta, nodes, steps_per_period, tolerance, max_periods).K
        if progress is not None:
            progress(index + 1, sigmas.size)
    return values
