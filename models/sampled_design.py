"""Double-pair pole placement for the sampled loop: the PID of eqs. (21)-(22) as the 2 kHz loop runs it.

The paper places the poles of the continuous loop, eqs. (23)-(24); the digital loop realises something
else (Fig. 8's forward-Euler map exceeds 1 below ~90 um, docs/controller.md). Here the design is made
for the loop that actually runs (:func:`~nfal.models.local_loop.discrete_loop_matrix`, ``"zoh"``): the
plant of eq. (20) held by the DAC for a sample, the discrete law of :mod:`nfal.models.control_law` with
its forward-Euler integrator and derivative filter.

Its characteristic polynomial det(z I - A_d) is affine in (k_p, k_i, k_d). Critical damping in pairs
asks for (z - z1)^2 (z - z2)^2, the z-images z = exp(-p T_s) of the paper's double pairs at -p1, -p2:

    det(z I - A_d(k)) = (z - z1)^2 (z^2 + a z + b),   a^2 = 4 b   (then z2 = -a / 2).

For a slow pole z1 the first condition is 4 linear equations in the 5 unknowns (k_p, k_i, k_d, a, b):
a line; the second is a quadratic along it. Of its real roots the one with the smaller |z2| (the faster
pair) is taken. As in the continuous design one degree of freedom, z1, is left; the closed loop's -3 dB
cut-off (now of the sampled transfer function r -> H at z = exp(j w T_s)) fixes it.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import linalg, optimize

from .errors import ConvergenceError
from .local_loop import discrete_loop_matrix
from .lpv import LPVCoefficients


class SampledLoop:
    """The local sampled loop of one equilibrium, as a function of its PID gains.

    Parameters
    ----------
    lpv : LPVCoefficients
        Eq. (20) at one equilibrium.
    omega_lpf : float
        Derivative filter cut-off (non-dimensional, time unit 1 / omega).
    step : float
        Sampling period omega T_s (non-dimensional).
    """

    def __init__(self, lpv: LPVCoefficients, omega_lpf: float, step: float) -> None:
        self.lpv, self.omega_lpf, self.step = lpv, float(omega_lpf), float(step)
        base = self.matrix((0.0, 0.0, 0.0))
        self._offset = np.poly(base)[1:]
        self._slopes = np.column_stack([np.poly(self.matrix(unit))[1:] - self._offset for unit in np.eye(3)])
        plant = np.zeros((3, 3))
        plant[:2, :2] = [[0.0, 1.0], [-float(lpv.alpha0), -float(lpv.alpha1)]]
        plant[1, 2] = float(lpv.beta0)
        self._hold_gain = linalg.expm(plant * self.step)[:2, 2]  # H, V per unit du held over a sample

    def matrix(self, gains) -> np.ndarray:
        """A_d of the loop with ``gains`` = (k_p, k_i, k_d) (non-dimensional)."""
        return discrete_loop_matrix(self.lpv, gains, self.omega_lpf, self.step, "zoh")

    def gains(self, slow_pole: float) -> tuple[float, float, float, float]:
        """(k_p, k_i, k_d, z2) placing a double pole at z1 = exp(-``slow_pole`` T_s) and a double pole z2.

        NaNs when no real gains do (the quadratic has no real root).
        """
        z1 = math.exp(-slow_pole * self.step)
        # (z - z1)^2 (z^2 + a z + b) = z^4 + (a - 2 z1) z^3 + (b - 2 z1 a + z1^2) z^2 + (z1^2 a - 2 z1 b) z + z1^2 b
        along_a = np.array([1.0, -2.0 * z1, z1**2, 0.0])
        along_b = np.array([0.0, 1.0, -2.0 * z1, z1**2])
        fixed = np.array([-2.0 * z1, z1**2, 0.0, 0.0])
        system = np.column_stack([self._slopes, -along_a, -along_b])
        particular = np.linalg.lstsq(system, fixed - self._offset, rcond=None)[0]
        direction = np.linalg.svd(system)[2][-1]
        (a0, b0), (a1, b1) = particular[3:], direction[3:]
        roots = np.roots([a1**2, 2.0 * a0 * a1 - 4.0 * b1, a0**2 - 4.0 * b0])  # a(t)^2 = 4 b(t)
        real = [t.real for t in roots if abs(t.imag) <= 1e-9 * max(abs(t), 1.0)]
        if not real:
            return (math.nan,) * 4
        solution = min((particular + t * direction for t in real), key=lambda x: abs(x[3]))
        kp, ki, kd, a, _ = (float(v) for v in solution)
        return kp, ki, kd, -0.5 * a

    def reference_gain(self, gains, frequency) -> np.ndarray:
        """|H / r| of the sampled loop at ``frequency`` (non-dimensional, up to pi / step): the reference
        enters through k_p (held by the DAC) and the integrator, eq. (21)-(22)."""
        kp, ki, _ = (float(g) for g in gains)
        loop = self.matrix(gains)
        entry = np.zeros(4)
        entry[:2] = self._hold_gain * kp
        entry[2] = self.step * ki
        z = np.exp(1j * np.atleast_1d(np.asarray(frequency, dtype=float)) * self.step)
        response = np.linalg.solve(z[:, None, None] * np.eye(4) - loop, np.broadcast_to(entry, (z.size, 4))[..., None])
        return np.abs(response[:, 0, 0])

    def bandwidth(self, slow_pole: float) -> float:
        """Lowest frequency (non-dimensional) where |H / r| falls through 1/sqrt(2), slow pole ``slow_pole``."""
        gains = self.gains(slow_pole)[:3]
        if not np.all(np.isfinite(gains)):
            raise ConvergenceError(f"no real sampled design for the slow pole {slow_pole:.4g}")
        nyquist = math.pi / self.step
        grid = np.geomspace(1e-4 * slow_pole, nyquist, 2000)
        below = np.flatnonzero(self.reference_gain(gains, grid) < 1.0 / math.sqrt(2.0))
        if below.size == 0 or below[0] == 0:
            raise ConvergenceError(f"no -3 dB crossing of the sampled loop for p1 = {slow_pole:.4g}")
        i = below[0]
        return float(optimize.brentq(lambda w: self.reference_gain(gains, w)[0] - 1.0 / math.sqrt(2.0),
                                     grid[i - 1], grid[i], xtol=1e-14, rtol=1e-12))
