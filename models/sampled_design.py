"""Double-pair pole placement for the sampled loop: the PID of eqs. (21)-(22) as the 2 kHz loop runs it.

The paper places the poles of the continuous loop, eqs. (23)-(24); the digital loop realises something
else (Fig. 8's forward-Euler map exceeds 1 below ~90 um, docs/controller.md). Here the design is made
for the loop that actually runs (:func:`~nfal.models.local_loop.sampled_loop_matrix`, ``"zoh"``): the
plant of eq. (20) held by the DAC for a sample, the discrete law of :mod:`nfal.models.control_law` with
its forward-Euler integrator and derivative filter.

Its characteristic polynomial det(z I - A_d) is affine in (k_p, k_i, k_d). Critical damping in pairs
asks for (z - z1)^2 (z - z2)^2, the z-images z = exp(-p T_s) of the paper's double pairs at -p1, -p2:

    det(z I - A_d(k)) = (z - z1)^2 (z^2 + a z + b),   a^2 = 4 b   (then z2 = -a / 2).

For a slow pole z1 the first condition is 4 linear equations in the 5 unknowns (k_p, k_i, k_d, a, b):
a line, x0 + a x1; the second is a quadratic along it. Of its real roots the one with the smaller |z2|
(the faster pair) is taken. As in the continuous design one degree of freedom, z1, is left; the closed loop's -3 dB
cut-off (now of the sampled transfer function r -> H at z = exp(j w T_s)) fixes it. With the law's reference zero
(:mod:`nfal.models.control_law`) the cut-off is that of r -> H through the reference filter, as the law runs it:
the filter takes the PI zero's lift of the bandwidth away, and a design blind to it would be slower than asked
for where that lift was large (with rho = 1 on eq. 6, p1 is 10.0 instead of 4.9 Hz at 50 um, docs/controller.md 2b).
"""

from __future__ import annotations

import math

import numpy as np
import scipy

from nfal.errors import ConvergenceError

from .local_loop import held_plant, sampled_loop_matrix
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
    reference_zero : float or None
        The law's reference zero rho; None: the reference as given.
    """

    def __init__(self, lpv: LPVCoefficients, omega_lpf: float, step: float,
                 reference_zero: float | None = None) -> None:
        self.lpv, self.omega_lpf, self.step = lpv, float(omega_lpf), float(step)
        self.reference_zero = reference_zero
        # A_d and its characteristic polynomial are affine in the gains: keep the offset and the slopes
        held = held_plant(lpv, self.step)
        self._matrix_offset = sampled_loop_matrix(held, (0.0, 0.0, 0.0), self.omega_lpf, self.step)
        units = [sampled_loop_matrix(held, unit, self.omega_lpf, self.step) for unit in np.eye(3)]
        self._matrix_slopes = np.array([m - self._matrix_offset for m in units])
        self._offset = np.poly(self._matrix_offset)[1:]
        self._slopes = np.column_stack([np.poly(m)[1:] - self._offset for m in units])
        self._hold_gain = held[1]  # H, V per unit du held over a sample

    def matrix(self, gains) -> np.ndarray:
        """A_d of the loop with ``gains`` = (k_p, k_i, k_d) (non-dimensional)."""
        return self._matrix_offset + np.tensordot(np.asarray(gains, dtype=float), self._matrix_slopes, axes=1)

    def gains(self, slow_pole):
        """(k_p, k_i, k_d, z2) placing a double pole at z1 = exp(-``slow_pole`` T_s) and a double pole z2.

        ``slow_pole`` may be an array (the four results are then arrays). NaNs where no real gains do.
        """
        z1 = np.exp(-np.asarray(slow_pole, dtype=float) * self.step)[..., None]
        zero, one = np.zeros_like(z1), np.ones_like(z1)
        # (z - z1)^2 (z^2 + a z + b) = z^4 + (a - 2 z1) z^3 + (b - 2 z1 a + z1^2) z^2 + (z1^2 a - 2 z1 b) z + z1^2 b:
        # with (k_p, k_i, k_d, b) as unknowns the coefficients are linear, x = x0 + a x1, and then b = a^2 / 4
        along_a = np.concatenate([one, -2.0 * z1, z1**2, zero], axis=-1)
        along_b = np.concatenate([zero, one, -2.0 * z1, z1**2], axis=-1)
        fixed = np.concatenate([-2.0 * z1, z1**2, zero, zero], axis=-1)
        system = np.concatenate([np.broadcast_to(self._slopes, z1.shape[:-1] + (4, 3)), -along_b[..., None]], axis=-1)
        x0 = np.linalg.solve(system, (fixed - self._offset)[..., None])[..., 0]
        x1 = np.linalg.solve(system, along_a[..., None])[..., 0]
        # a^2 / 4 - x1_b a - x0_b = 0, z2 = -a / 2 = -x1_b -+ sqrt(x1_b^2 + x0_b): the smaller |z2|, the faster pair
        centre = -x1[..., 3]
        with np.errstate(invalid="ignore"):
            spread = np.sqrt(centre**2 + x0[..., 3])
        fast = np.where(np.abs(centre - spread) < np.abs(centre + spread), centre - spread, centre + spread)
        kp, ki, kd = (x0[..., i] - 2.0 * fast * x1[..., i] for i in range(3))
        return kp, ki, kd, fast

    def reference_response(self, gains) -> tuple[np.ndarray, np.ndarray]:
        """(numerator, denominator) of H / r (z) of the sampled loop: the reference enters through k_p (held
        by the DAC) and the integrator, eqs. (21)-(22). For one input b and output c,
        c (zI - A)^-1 b = (det(zI - A + b c) - det(zI - A)) / det(zI - A)."""
        gains = [float(g) for g in gains]
        kp, ki = gains[:2]
        loop = self.matrix(gains)
        entry = np.zeros(4)
        entry[:2] = self._hold_gain * kp
        entry[2] = self.step * ki
        denominator = np.poly(loop)
        output = np.array([1.0, 0.0, 0.0, 0.0])  # H
        return np.poly(loop - np.outer(entry, output)) - denominator, denominator

    def reference_filter(self, gains, slow_pole: float) -> tuple[np.ndarray, np.ndarray]:
        """(numerator, denominator) of the law's reference filter F(z) for these gains and slow pole: with
        d = 1 - T_s k_i / k_p (the PI zero) and b = min(1, rho k_i / (k_p p1)), the law's target is
        b r + (1 - b) l with l_k = d l_{k-1} + (1 - d) r_k, so F = (b (z - d) + (1 - b)(1 - d) z) / (z - d)."""
        kp, ki = (float(g) for g in gains[:2])
        if self.reference_zero is None or kp <= 0.0 or ki <= 0.0:
            return np.array([1.0]), np.array([1.0])
        d = 1.0 - self.step * ki / kp
        b = min(1.0, self.reference_zero * ki / (kp * slow_pole))
        return np.array([b + (1.0 - b) * (1.0 - d), -b * d]), np.array([1.0, -d])

    def reference_gain(self, gains, frequency) -> np.ndarray:
        """|H / r| of the sampled loop at ``frequency`` (non-dimensional, up to pi / step)."""
        return _gain(*self.reference_response(gains), frequency, self.step)

    def bandwidth(self, slow_pole: float) -> float:
        """Lowest frequency (non-dimensional) where |H / r| falls through 1/sqrt(2), slow pole ``slow_pole``."""
        gains = [float(g) for g in self.gains(slow_pole)[:3]]
        if not np.all(np.isfinite(gains)):
            raise ConvergenceError(f"no real sampled design for the slow pole {slow_pole:.4g}")
        numerator, denominator = (np.polymul(loop, law) for loop, law in zip(self.reference_response(gains),
                                                                             self.reference_filter(gains, slow_pole)))
        excess = lambda w: _gain(numerator, denominator, w, self.step) - 1.0 / math.sqrt(2.0)  # noqa: E731
        grid = np.geomspace(1e-4 * slow_pole, math.pi / self.step, 600)  # to Nyquist; brackets the first crossing
        below = np.flatnonzero(excess(grid) < 0.0)
        if below.size == 0 or below[0] == 0:
            raise ConvergenceError(f"no -3 dB crossing of the sampled loop for p1 = {slow_pole:.4g}")
        i = below[0]
        return float(scipy.optimize.brentq(lambda w: float(excess(w)[0]), grid[i - 1], grid[i], xtol=1e-14, rtol=1e-12))


def _gain(numerator: np.ndarray, denominator: np.ndarray, frequency, step: float) -> np.ndarray:
    """|N / D| at z = exp(j w step) for the (non-dimensional) frequencies ``frequency``."""
    z = np.exp(1j * np.atleast_1d(np.asarray(frequency, dtype=float)) * step)
    return np.abs(np.polyval(numerator, z) / np.polyval(denominator, z))
