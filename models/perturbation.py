"""K(sigma) by the perturbation route of eqs. (8)-(12): exact as delta -> 0, for any excitation shape.

With the gap H = Hbar (1 - delta eps_hat sin T) of eq. (8) and P = 1 + delta Pi_A + delta^2 Pi_B (eq. 9),
the O(delta) balance of Reynolds' equation (3) for Pi_A = Pi_1 cos T + Pi_2 sin T (eq. 10) is, with
the complex amplitude Pi = Pi_1 - i Pi_2 and L = (1/R) d/dR (R d/dR),

    (L - i sigma) Pi = -sigma eps_hat,    Pi'(0) = 0,  Pi(1) = 0          (BCs 5)

The period average of the O(delta^2) balance integrates once to
Pi_5' = -(Pi_1^2 + Pi_2^2)'/4 + (3/2) eps_hat Pi_2', and eq. (12) with one integration by parts gives

    K(sigma) = 2 int R Pi_5 dR = -1/2 int R |Pi|^2 dR + 3/2 int R (2 eps_hat + R eps_hat') Pi_2 dR.

Both are discretised by the same conservative finite volumes as the time-marching film
(node-centred, second order in the radial step).
"""

from __future__ import annotations

import numpy as np
import scipy

from nfal.errors import InvalidParameterError

from .excitation import ExcitationShape

DEFAULT_NODES = 401


#: Most radial nodes of a film grid: K converges to 1e-6 by about 401 (docs/film_solvers.md).
MAX_GRID_NODES = 20_001


def radial_grid(nodes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nodes R_n = n / (N - 1), their faces and control volumes int R dR of the finite-volume scheme.

    Returns ``(R, faces, volumes)``; ``faces[n]`` is R at the face between nodes n and n + 1.
    """
    if not isinstance(nodes, (int, np.integer)) or not 5 <= nodes <= MAX_GRID_NODES:
        raise InvalidParameterError("nodes", nodes, f"a whole number in [5, {MAX_GRID_NODES}]")
    R = np.linspace(0.0, 1.0, nodes)
    step = R[1]
    faces = R[:-1] + 0.5 * step
    volumes = R * step
    volumes[0] = step**2 / 8.0
    volumes[-1] = (1.0 - (1.0 - 0.5 * step) ** 2) / 2.0
    return R, faces, volumes


def as_squeeze_numbers(sigma) -> np.ndarray:
    """``sigma`` as a 1-D float array, every value finite and > 0."""
    values = np.atleast_1d(np.asarray(sigma, dtype=float))
    if values.ndim != 1 or values.size == 0 or not np.all(np.isfinite(values)) or np.any(values <= 0):
        raise InvalidParameterError("sigma", sigma, "one or more finite squeeze numbers > 0")
    return values


def first_order_pressure(shape: ExcitationShape, sigma: float,
                         nodes: int = DEFAULT_NODES) -> tuple[np.ndarray, np.ndarray]:
    """The O(delta) pressure amplitude Pi = Pi_1 - i Pi_2 of eq. (10) on the radial nodes.

    Returns ``(R, Pi)``; the pressure is P = 1 + delta Re(Pi exp(i T)) + O(delta^2).
    """
    sigma = float(as_squeeze_numbers(sigma)[0])
    R, faces, volumes = radial_grid(nodes)
    step = R[1]
    unknown = nodes - 1  # the rim node is held at Pi = 0
    conductance = faces / step  # R_{n+1/2} / dR
    banded = np.zeros((3, unknown), dtype=complex)
    banded[0, 1:] = conductance[: unknown - 1]
    banded[2, :-1] = conductance[: unknown - 1]
    banded[1] = (-conductance[:unknown] - np.concatenate(([0.0], conductance[: unknown - 1]))
                 - 1j * sigma * volumes[:unknown])
    rhs = -sigma * volumes[:unknown] * shape(R[:unknown])
    amplitude = np.zeros(nodes, dtype=complex)
    amplitude[:unknown] = scipy.linalg.solve_banded((1, 1), banded, rhs.astype(complex))
    return R, amplitude


def perturbation_K(shape: ExcitationShape, sigma, nodes: int = DEFAULT_NODES) -> np.ndarray:
    """The calibration function K(sigma) of eq. (12) in the limit delta -> 0, for each ``sigma``."""
    sigmas = as_squeeze_numbers(sigma)
    R, _, volumes = radial_grid(nodes)
    weight = 2.0 * shape(R) + R * shape.slope(R)
    values = np.empty_like(sigmas)
    for index, value in enumerate(sigmas):
        _, amplitude = first_order_pressure(shape, value, nodes)
        pi_2 = -amplitude.imag
        values[index] = -0.5 * np.sum(volumes * np.abs(amplitude) ** 2) + 1.5 * np.sum(volumes * weight * pi_2)
    return values


def trapped_gas_K(shape: ExcitationShape) -> float:
    """K as sigma -> infinity: int R eps_hat^2 dR + 3/4 eps_hat(1)^2 (5/4 for the piston).

    In that limit P H is constant in time away from the rim (Pi_2 = eps_hat, Pi_1 = 0), and the
    rim's boundary layer carries the jump of Pi_2 from eps_hat(1) to 0.
    """
    second_moment, _ = scipy.integrate.quad(lambda r: r * float(shape(r)) ** 2, 0.0, 1.0, limit=400)
    return second_moment + 0.75 * shape.edge_value() ** 2


def piston_K_exact(sigma) -> np.ndarray:
    """Closed-form K(sigma) for the uniform (piston) excitation, delta -> 0.

    Pi = -i (1 - I0(k R) / I0(k)), k = sqrt(i sigma), gives
    K = 5/4 - 2 Re(r / k) - Im(k r) / (2 sigma), r = I1(k) / I0(k). Limits: 5/4 as sigma -> inf,
    5 sigma^2 / 192 as sigma -> 0.
    """
    sigmas = as_squeeze_numbers(sigma)
    k = np.sqrt(1j * sigmas)
    ratio = scipy.special.ive(1, k) / scipy.special.ive(0, k)  # the exponential scalings cancel
    return 1.25 - 2.0 * np.real(ratio / k) - np.imag(k * ratio) / (2.0 * sigmas)
