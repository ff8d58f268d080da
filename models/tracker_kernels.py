"""The transducer's envelope step (T4) and the PLL's sample (P1-P2) as kernels on floats: what
:meth:`Transducer.step <nfal.models.transducer.Transducer.step>` and :meth:`PhaseLockedLoop.step
<nfal.models.pll.PhaseLockedLoop.step>` compute, and the ResonanceTracker's compiled core (``tracker_core.py``) with
them. The complex arithmetic is spelled out as CPython does it (``_Py_c_prod``, ``_Py_c_quot`` in
Objects/complexobject.c; a float operand enters as ``x + 0j``) and a square as a product, so that Python and numba
give the same bits.
"""

from __future__ import annotations

import math

from . import jit

TWO_PI = 2.0 * math.pi


@jit.kernel
def _product(ar, ai, br, bi):
    return ar * br - ai * bi, ar * bi + ai * br


@jit.kernel
def _quotient(ar, ai, br, bi):
    if abs(br) >= abs(bi):
        ratio = bi / br
        denominator = br + bi * ratio
        return (ar + ai * ratio) / denominator, (ai - ar * ratio) / denominator
    ratio = br / bi
    denominator = br * ratio + bi
    return (ar * ratio + ai) / denominator, (ai * ratio - ar) / denominator


@jit.kernel
def envelope_step(envelope_re, envelope_im, voltage, drive_hz, resonance_hz, quality_factor, metres_per_volt, dt):
    """The envelope A [m] after ``dt`` s with the inputs held, exactly (T4): A + (e^(lambda dt) - 1) (A + b V / lambda),
    at the current resonance ``resonance_hz`` (shift included)."""
    omega_r = TWO_PI * resonance_hz
    omega = TWO_PI * drive_hz
    omega_r2 = omega_r * omega_r  # squares as products: CPython's ** 2 is pow(), numba's x * x, not always equal
    rate_re, rate_im = -omega_r / (2.0 * quality_factor), (omega_r2 - omega * omega) / (2.0 * omega)
    drive_re, drive_im = _product(0.0, 2.0, omega, 0.0)  # 2j * omega
    forcing_re, forcing_im = _quotient((metres_per_volt / quality_factor) * omega_r2 * voltage, 0.0,
                                       drive_re, drive_im)
    x, y = _product(rate_re, rate_im, dt, 0.0)  # lambda dt
    half = math.sin(y / 2.0)
    growth_re, growth_im = math.expm1(x) * math.cos(y) - 2.0 * (half * half), math.exp(x) * math.sin(y)
    ratio_re, ratio_im = _quotient(forcing_re, forcing_im, rate_re, rate_im)
    change_re, change_im = _product(growth_re, growth_im, envelope_re + ratio_re, envelope_im + ratio_im)
    return envelope_re + change_re, envelope_im + change_im


@jit.kernel
def phase_error(envelope_re, envelope_im):
    """arg A + pi/2 wrapped into (-pi, pi] [rad]: A's phase is in [-pi, pi], so the sum lies in [-pi/2, 3pi/2], where
    this is math.remainder's wrap exactly (x - 2 pi is exact there)."""
    error = math.atan2(envelope_im, envelope_re) + math.pi / 2.0
    return error - TWO_PI if error > math.pi else error


@jit.kernel
def pll_sample(envelope_re, envelope_im, frequency, integrator, lock_count, locked, centre_hz, proportional, integral,
               period, pull_range, lock_threshold, lock_samples, min_amplitude, enabled):
    """One sample of the PLL from its state (frequency [Hz], integrator [Hz], lock count, locked) and the envelope A
    measured: its next state and the phase error, (frequency, integrator, phase error, lock count, locked)."""
    if math.hypot(envelope_re, envelope_im) < min_amplitude:
        return frequency, integrator, 0.0, 0, False
    error = phase_error(envelope_re, envelope_im)
    if not enabled:
        return centre_hz, 0.0, error, 0, False
    integrator = integrator + integral * period * error
    offset = proportional * error + integrator
    clamped = min(max(offset, -pull_range), pull_range)
    integrator += clamped - offset  # back-calculation: the integral holds at the pull-range limit
    count = min(lock_count + 1, lock_samples) if abs(error) < lock_threshold else 0
    return centre_hz + clamped, integrator, error, count, count >= lock_samples
