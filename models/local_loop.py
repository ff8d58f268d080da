"""The local loop of Sec. 4.1 at one equilibrium: plant of eq. (20) with fixed PID gains, eqs. (21)-(22).

State Upsilon = (dHbar, dHbar/dT, eta, psi), time unit 1 / omega, zero reference deviation:

    dHbar'  = V
    V'      = -alpha0 dHbar - alpha1 V + beta0 du,     du = -k_p dHbar + eta - k_d psi
    eta'    = -k_i dHbar
    psi'    = omega_L (V - psi).

Two discretisations at the sampling period T_s:

``"forward_euler"`` (the paper's Fig. 8): the whole loop, plant included, by forward Euler,
    A_d = I + T_s A, so z = 1 + T_s s for every continuous closed-loop pole s.
``"zoh"`` (what the digital loop of :mod:`nfal.models.control_law` and the simulation see): the plant
    sampled exactly behind a zero-order hold, the controller by forward Euler, the derivative fed by the
    measured height: psi_k = (1 - T_s omega_L) psi_{k-1} + omega_L (H_k - H_{k-1}).

Both are affine in the gains (k_p, k_i, k_d), and so are their characteristic polynomials' coefficients
(the gains form a state feedback of the open loop augmented by the integrator and the filter).
"""

from __future__ import annotations

import numpy as np
import scipy

from nfal.errors import InvalidParameterError

from .lpv import LPVCoefficients

DISCRETISATIONS = ("forward_euler", "zoh")


def continuous_loop_matrix(plant: LPVCoefficients, gains, omega_lpf: float) -> np.ndarray:
    """A of the local loop (state dHbar, dHbar/dT, eta, psi; time unit 1 / omega)."""
    a0, a1, b0 = float(plant.alpha0), float(plant.alpha1), float(plant.beta0)
    kp, ki, kd = (float(g) for g in gains)
    return np.array([[0.0, 1.0, 0.0, 0.0],
                     [-a0 - b0 * kp, -a1, b0, -b0 * kd],
                     [-ki, 0.0, 0.0, 0.0],
                     [0.0, omega_lpf, 0.0, -omega_lpf]])


def held_plant(plant: LPVCoefficients, step: float) -> tuple[np.ndarray, np.ndarray]:
    """(Phi, Gamma): eq. (20) over one sample of ``step`` with its input held,
    (H, V)_{k+1} = Phi (H, V)_k + Gamma du_k."""
    augmented = np.zeros((3, 3))
    augmented[:2, :2] = [[0.0, 1.0], [-float(plant.alpha0), -float(plant.alpha1)]]
    augmented[1, 2] = float(plant.beta0)
    exact = scipy.linalg.expm(augmented * step)
    return exact[:2, :2], exact[:2, 2]


def sampled_loop_matrix(held: tuple[np.ndarray, np.ndarray], gains, omega_lpf: float, step: float) -> np.ndarray:
    """The ``"zoh"`` loop's transition matrix from the plant's :func:`held_plant` ``held``."""
    phi, gamma = held
    kp, ki, kd = (float(g) for g in gains)
    # State (H, V, eta, xi) with psi = omega_L (H - xi) and xi_{k+1} = xi_k + step omega_L (H_k - xi_k):
    # the same recursion for psi as the module docstring's, written without H_{k-1}.
    command = np.array([-kp - kd * omega_lpf, 0.0, 1.0, kd * omega_lpf])  # du_k in terms of the state
    loop = np.zeros((4, 4))
    loop[:2, :2] = phi
    loop[:2, :] += np.outer(gamma, command)
    loop[2] = [-step * ki, 0.0, 1.0, 0.0]
    loop[3] = [step * omega_lpf, 0.0, 0.0, 1.0 - step * omega_lpf]
    return loop


def discrete_loop_matrix(plant: LPVCoefficients, gains, omega_lpf: float, step: float,
                         discretisation: str = "forward_euler") -> np.ndarray:
    """The local loop's transition matrix over one sample of ``step`` (non-dimensional, omega T_s)."""
    if discretisation == "forward_euler":
        return np.eye(4) + step * continuous_loop_matrix(plant, gains, omega_lpf)
    if discretisation != "zoh":
        raise InvalidParameterError("discretisation", discretisation, f"one of {DISCRETISATIONS}")
    return sampled_loop_matrix(held_plant(plant, step), gains, omega_lpf, step)
