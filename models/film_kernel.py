"""The squeeze film's discretisation in one place: the face fluxes of Reynolds' equation, their exact tridiagonal
Jacobian, and the Thomas algorithm that solves it. The fixed film (:mod:`nfal.models.reynolds`, K(sigma) by time
marching) and the coupled film and object (:mod:`nfal.models.coupled`) both assemble their Newton steps from these
``numba.njit`` kernels.

On the node-centred finite volumes of :func:`~nfal.models.perturbation.radial_grid`, with u = P - 1 the gauge
pressure, the flux through face f (between nodes f and f + 1) is

    F_f = c_f (P_{f+1}^2 - P_f^2) / 2 = c_f (u_{f+1} - u_f)(2 + u_{f+1} + u_f) / 2,

written so to avoid cancellation, where the face's conductance c_f = R_f H_f^3 / dR carries whatever scale the
caller's equation puts on the flux (1 / sigma for the fixed film, 1 / Lambda for the coupled one). The rim node
(P = 1) is not an unknown, and no flux crosses the axis.
"""

from __future__ import annotations

import numba

from . import numba_cache

numba_cache.install()  # before the kernels below: their compiled code outlives an FMU's temporary folder


@numba.njit(cache=True)
def face_fluxes(u, conductances, flux, faces):
    """``flux[f]`` = F_f for the first ``faces`` faces, from the gauge pressures ``u`` and the faces' conductances."""
    for f in range(faces):
        flux[f] = 0.5 * conductances[f] * (u[f + 1] - u[f]) * (2.0 + u[f + 1] + u[f])


@numba.njit(cache=True)
def flux_jacobian(u, conductances, lower, diag, upper):
    """The net flux F_n - F_{n-1} of each unknown node n (every node but the rim) differentiated by u: its negative
    into ``lower`` (by u_{n-1}), ``upper`` (by u_{n+1}) and ``diag`` (by u_n; the caller adds its mass term)."""
    below = 0.0  # no face below the axis node
    for n in range(diag.shape[0]):
        diag[n] = (conductances[n] + below) * (1.0 + u[n])
        lower[n] = -below * (1.0 + u[n - 1]) if n > 0 else 0.0
        upper[n] = -conductances[n] * (1.0 + u[n + 1])
        below = conductances[n]


@numba.njit(cache=True)
def thomas_factor(lower, diag, upper, work):
    """Factor a tridiagonal matrix (``lower[i]`` multiplies x[i-1], ``upper[i]`` x[i+1]) into ``work`` (size >= 2n):
    ``work[i]`` the modified upper diagonal, ``work[n + i]`` the reciprocal of pivot i.

    No pivoting: the film Jacobians are diagonally dominant (the BDF2 mass term plus an M-matrix of conductances).
    """
    n = diag.shape[0]
    work[n] = 1.0 / diag[0]
    for i in range(1, n):
        work[i] = upper[i - 1] * work[n + i - 1]
        work[n + i] = 1.0 / (diag[i] - lower[i] * work[i])


@numba.njit(cache=True)
def thomas_substitute(lower, work, rhs, out):
    """Solve the system :func:`thomas_factor` factored into ``work`` for ``rhs``, into ``out``."""
    n = rhs.shape[0]
    out[0] = rhs[0] * work[n]
    for i in range(1, n):
        out[i] = (rhs[i] - lower[i] * out[i - 1]) * work[n + i]
    for i in range(n - 2, -1, -1):
        out[i] -= work[i + 1] * out[i + 1]


@numba.njit(cache=True)
def thomas_solve(lower, diag, upper, rhs, out, work):
    """Solve a tridiagonal system (the Thomas algorithm): :func:`thomas_factor`, then :func:`thomas_substitute`."""
    thomas_factor(lower, diag, upper, work)
    thomas_substitute(lower, work, rhs, out)
