"""The ultrasonic transducer's resonance in slow time: a driven second-order resonator as a complex envelope.

Sec. 4 and the closing argument of the paper: the actuator is driven at its resonance (a lightly damped
mode), so "small deviations from the resonance can reduce the excitation magnitude dramatically". The
model is the motional branch of the Butterworth-Van Dyke equivalent circuit seen as a mechanical
resonator, with the excitation magnitude ||a|| as its coordinate x [m]:

    x'' + (omega_r / Q) x' + omega_r^2 x = g omega_r^2 V cos(theta),    theta' = omega        (T1)

V the drive voltage amplitude [V], theta the drive phase, omega = 2 pi f the drive frequency, omega_r =
2 pi (f_r + shift) the (shifting) resonance, Q the quality factor and g = metres_per_volt / Q so that the
steady-state amplitude at resonance is metres_per_volt * V, whatever the shift (the shift moves the peak;
its height is the calibrated map of Sec. 3.3).

Slow time. With x = Re{A e^{i theta}} and A slowly varying (|A'| << omega |A|: first-order averaging,
dropping A'' and the damping of A'), (T1) becomes the envelope equation

    A' = lambda A + b V,   lambda = -omega_r / (2 Q) + i (omega_r^2 - omega^2) / (2 omega),
                           b = g omega_r^2 / (2 i omega)                                       (T2)

A is the complex amplitude of the displacement relative to the drive's phase: ||a|| = |A| and arg A is
the displacement's phase relative to the drive (-90 deg at resonance, towards 0 below it, towards -180
above it). (T2) keeps omega_r^2 - omega^2 unexpanded, so its steady state

    A_ss = -b V / lambda = g omega_r^2 V / (omega_r^2 - omega^2 + i omega omega_r / Q)          (T3)

is exactly the steady-state response of (T1), and its decay rate is exactly omega_r / (2 Q): the amplitude
time constant tau = 2 Q / omega_r (5.6 ms at 28.5 kHz, Q = 500). With V, omega and omega_r held over a
step dt, (T2) is linear with constant coefficients, and

    A(t + dt) = e^{lambda dt} A(t) + (e^{lambda dt} - 1) / lambda * b V                          (T4)

is its exact solution (computed with expm1). The quasi-static mode uses (T3) at the current inputs.

Near resonance (|f - f_r| << f_r) the steady-state magnitude is metres_per_volt V / sqrt(1 + x^2) and the
phase error arg A + pi/2 is atan(x), with x = 2 Q (f_r - f) / f_r.

Parameter choice (an assumption: the paper gives no transducer data; recorded in docs/cosimulation.md):
Q = 500. The paper's closing argument is that a fixed drive frequency is impractical; with the 0.2 %
resonance drift of the acceptance check the fixed-frequency response 1 / sqrt(1 + (2 Q 0.002)^2) falls
below one half only if Q > 433; 500 gives 0.447, a light damping typical of a loaded piezoelectric
Langevin stack (Q of a few hundred to a thousand).
"""

from __future__ import annotations

import cmath
import dataclasses
import math

from nfal.errors import InvalidParameterError, require_finite, require_non_negative, require_positive

from . import tracker_kernels
from .rig import RigParameters
from .plausibility import FREQUENCY_RANGE_HZ, MAX_METRES_PER_VOLT, require_plausible

#: Nominal resonance [Hz] (the rig's nominal frequency).
RESONANCE_FREQUENCY_HZ = RigParameters.frequency
#: Quality factor of the loaded transducer (assumption; see the module docstring).
QUALITY_FACTOR = 500.0
#: ||a|| per volt of drive amplitude at resonance in steady state [m/V] (assumption, as the Controller FMU).
METRES_PER_VOLT = 0.1e-6


@dataclasses.dataclass(frozen=True)
class Transducer:
    """The driven resonator (T1) in slow time (T2); :meth:`step` and :meth:`steady_state` are pure functions.

    Parameters
    ----------
    resonance_frequency_hz : float
        Nominal resonance f_r [Hz] (shift 0).
    quality_factor : float
        Q [-], > 0.5 (an underdamped mode).
    metres_per_volt : float
        Steady-state ||a|| per volt at resonance [m/V].
    """

    resonance_frequency_hz: float = RESONANCE_FREQUENCY_HZ
    quality_factor: float = QUALITY_FACTOR
    metres_per_volt: float = METRES_PER_VOLT

    def __post_init__(self) -> None:
        object.__setattr__(self, "resonance_frequency_hz", require_plausible(
            "resonance_frequency_hz", require_positive("resonance_frequency_hz", self.resonance_frequency_hz),
            FREQUENCY_RANGE_HZ[1], "Hz", FREQUENCY_RANGE_HZ[0]))
        q = require_positive("quality_factor", self.quality_factor)
        if q <= 0.5:
            raise InvalidParameterError("quality_factor", self.quality_factor, "> 0.5 (an underdamped resonance)")
        object.__setattr__(self, "quality_factor", q)
        object.__setattr__(self, "metres_per_volt", require_plausible(
            "metres_per_volt", require_positive("metres_per_volt", self.metres_per_volt), MAX_METRES_PER_VOLT, "m/V"))

    # --- derived quantities -------------------------------------------------------------------------
    def resonance_hz(self, resonance_shift_hz: float = 0.0) -> float:
        """The current resonance f_r + shift [Hz] (> 0)."""
        shift = require_finite("resonance_shift_hz", resonance_shift_hz, "a finite shift [Hz]")
        resonance = self.resonance_frequency_hz + shift
        if not resonance > 0:
            raise InvalidParameterError("resonance_shift_hz", resonance_shift_hz,
                                        f"> {-self.resonance_frequency_hz:g} Hz (the resonance must stay positive)")
        return resonance

    def time_constant_s(self, resonance_shift_hz: float = 0.0) -> float:
        """Envelope time constant tau = 2 Q / omega_r [s] of (T2)."""
        return 2.0 * self.quality_factor / (2.0 * math.pi * self.resonance_hz(resonance_shift_hz))

    @property
    def phase_gain_rad_per_hz(self) -> float:
        """d(phase error)/d(f_r - f) at resonance = 2 Q / f_r [rad/Hz] (= 2 pi tau)."""
        return 2.0 * self.quality_factor / self.resonance_frequency_hz

    def _checked(self, voltage_v: float, drive_frequency_hz: float, resonance_shift_hz: float
                 ) -> tuple[float, float, float]:
        """(voltage [V], drive frequency [Hz], the current resonance [Hz]), each checked."""
        return (require_non_negative("voltage_v", voltage_v, "a finite amplitude >= 0 V"),
                require_positive("drive_frequency_hz", drive_frequency_hz), self.resonance_hz(resonance_shift_hz))

    def _coefficients(self, voltage_v: float, drive_frequency_hz: float, resonance_shift_hz: float
                      ) -> tuple[complex, complex]:
        """(lambda [1/s], b V [m/s]) of (T2) at the given inputs (checked)."""
        voltage, drive, resonance = self._checked(voltage_v, drive_frequency_hz, resonance_shift_hz)
        omega_r = 2.0 * math.pi * resonance
        omega = 2.0 * math.pi * drive
        rate = complex(-omega_r / (2.0 * self.quality_factor), (omega_r ** 2 - omega ** 2) / (2.0 * omega))
        forcing = (self.metres_per_volt / self.quality_factor) * omega_r ** 2 * voltage / (2j * omega)
        return rate, forcing

    # --- the model ------------------------------------------------------------------------------------
    def steady_state(self, voltage_v: float, drive_frequency_hz: float, resonance_shift_hz: float = 0.0) -> complex:
        """The steady-state envelope A_ss [m] of (T3): the quasi-static response at the current detuning."""
        rate, forcing = self._coefficients(voltage_v, drive_frequency_hz, resonance_shift_hz)
        return -forcing / rate

    def step(self, envelope_m: complex, voltage_v: float, drive_frequency_hz: float, resonance_shift_hz: float,
             dt_s: float) -> complex:
        """Advance the envelope A [m] by ``dt_s`` [s] with the inputs held: the exact solution (T4)."""
        try:
            envelope = complex(envelope_m)
        except (TypeError, ValueError):
            raise InvalidParameterError("envelope_m", envelope_m, "a finite complex amplitude [m]") from None
        if not cmath.isfinite(envelope):
            raise InvalidParameterError("envelope_m", envelope_m, "a finite complex amplitude [m]")
        dt = require_positive("dt_s", dt_s)
        voltage, drive, resonance = self._checked(voltage_v, drive_frequency_hz, resonance_shift_hz)
        return complex(*tracker_kernels.envelope_step(envelope.real, envelope.imag, voltage, drive, resonance,
                                                      self.quality_factor, self.metres_per_volt, dt))

    @staticmethod
    def amplitude(envelope_m: complex) -> float:
        """||a|| = |A| [m]."""
        return abs(envelope_m)

    @staticmethod
    def phase(envelope_m: complex) -> float:
        """Phase of the displacement relative to the drive, arg A [rad] in (-pi, pi] (-pi/2 at resonance)."""
        return cmath.phase(envelope_m)
