"""Resonance tracking (Fig. 7, Sec. 4.2, [13]): a digital phase-locked loop that drives the transducer at resonance.

The loop, at its own sample rate 1/T (per sample k):

    e_k = wrap(arg A_k + pi/2)                           phase detector: the displacement's phase relative
                                                          to the drive, + 90 deg (0 at resonance), in (-pi, pi]
    I_k = I_{k-1} + K_i T e_k                             PI loop filter (backward-Euler integral) ...
    f_k = clamp(f_0 + K_p e_k + I_k, f_0 +- pull range)   ... moving the drive frequency [Hz], held until k+1
                                                          (clamped with back-calculation of I_k)
    locked_k = |e_k| < threshold for lock_samples samples in a row

Below resonance the displacement lags the drive by less than 90 deg, so e > 0 and the loop raises f.

Gain design from a bandwidth B [Hz]. Near resonance the transducer (models/transducer.py) maps the
detuning f_r - f to the phase error through a first-order lag, e' = -e / tau + (G / tau) (f_r - f), with
G = 2 Q / f_r [rad/Hz] and tau = 2 Q / omega_r; with the frequency held over a sample, exactly

    e_{k+1} = p e_k + G (1 - p) (f_r - f_k),    p = exp(-T / tau)                      (P1)

The PI filter is C(z) = K (z - p) / (z - 1) with K = K_p + K_i T: its zero cancels the transducer's pole,
the open loop is K G (1 - p) / (z - 1), and the closed loop from the resonance to the drive frequency
is first order with the pole c = exp(-2 pi B T):

    K = (1 - c) / (G (1 - p)),   K_p = K p,   K_i = K (1 - p) / T                      (P2)

i.e. a bandwidth of B Hz, a time constant 1/(2 pi B), and a ramp of the resonance (r Hz/s) followed with
a lag of about r / (2 pi B) Hz. The quasi-static transducer is the limit tau -> 0 (p = 0): a pure
integral loop with the same closed-loop pole. The linear design holds within the transducer's half-power
band |f - f_r| < f_r / (2 Q); outside it the phase error saturates towards +-90 deg with the right sign,
so the loop pulls in from anywhere in the pull range, more slowly.

Defaults and why: B = 10 Hz, well below the sample rate (2 kHz) and the transducer's half-power band
(28.5 Hz at Q = 500), and fast against thermal drift: a 0.2 % ramp over 0.5 s (114 Hz/s) is followed
with a lag of 1.8 Hz, a loss of ||a|| of 0.2 %. Lock threshold 0.1 rad: in steady state ||a|| is
cos(e) of its resonant value, so locked means within 0.5 %. 20 samples (10 ms) in a row declare lock.
Pull range 1 % of f_0 (10 half-power bandwidths).

The functions are pure (python-control ``nlsys`` style): :meth:`PhaseLockedLoop.step` and
:meth:`ResonanceTracker.advance` take a state and return the next one, so the FMU can save and restore it.
"""

from __future__ import annotations

import cmath
import dataclasses
import functools
import logging
import math
from collections.abc import Callable

import numpy as np

from nfal.errors import InvalidParameterError, require_positive

from . import tracker_kernels
from .table2 import SAMPLING_RATE_HZ
from .transducer import Transducer

logger = logging.getLogger(__name__)

#: Default PLL sample rate [Hz] (the loop's, Table 2).
PLL_RATE_HZ = SAMPLING_RATE_HZ
#: Default closed-loop bandwidth of the PLL [Hz] (see the module docstring).
PLL_BANDWIDTH_HZ = 10.0
#: Default lock threshold on |phase error| [rad]: ||a|| within cos(0.1) = 99.5 % of resonance.
LOCK_THRESHOLD_RAD = 0.1
#: Default number of samples in a row below the threshold to declare lock.
LOCK_SAMPLES = 20
#: Default pull range as a fraction of the centre frequency.
PULL_RANGE_FRACTION = 0.01
#: Below this displacement amplitude [m] the phase is not measurable: the loop holds, unlocked.
MIN_AMPLITUDE_M = 1e-12


def wrap_phase(angle_rad: float) -> float:
    """``angle_rad`` wrapped into (-pi, pi]."""
    wrapped = math.remainder(float(angle_rad), 2.0 * math.pi)
    return math.pi if wrapped == -math.pi else wrapped


def phase_error(envelope_m: complex) -> float:
    """The phase detector: arg A + pi/2, wrapped [rad]; 0 at resonance, > 0 below it, < 0 above it."""
    envelope = complex(envelope_m)
    return tracker_kernels.phase_error(envelope.real, envelope.imag)


@dataclasses.dataclass(frozen=True)
class PllGains:
    """PI loop-filter gains: proportional [Hz/rad] and integral [Hz/(rad s)]."""

    proportional_hz_per_rad: float
    integral_hz_per_rad_s: float


def design_gains(bandwidth_hz: float, sample_rate_hz: float, phase_gain_rad_per_hz: float,
                 time_constant_s: float) -> PllGains:
    """PI gains (P2) for a closed-loop bandwidth ``bandwidth_hz`` [Hz] around the transducer (P1).

    Parameters
    ----------
    bandwidth_hz : float
        B [Hz], below sample_rate_hz / 10.
    sample_rate_hz : float
        PLL sample rate 1/T [Hz].
    phase_gain_rad_per_hz : float
        G = 2 Q / f_r [rad/Hz], the steady-state phase error per Hz of detuning.
    time_constant_s : float
        Transducer envelope time constant tau = 2 Q / omega_r [s]; 0 for the quasi-static transducer.
    """
    rate = require_positive("sample_rate_hz", sample_rate_hz)
    bandwidth = require_positive("bandwidth_hz", bandwidth_hz)
    if bandwidth >= rate / 10.0:
        raise InvalidParameterError("bandwidth_hz", bandwidth_hz, f"below a tenth of the sample rate, {rate / 10:g} Hz")
    gain = require_positive("phase_gain_rad_per_hz", phase_gain_rad_per_hz)
    if not (math.isfinite(float(time_constant_s)) and float(time_constant_s) >= 0):
        raise InvalidParameterError("time_constant_s", time_constant_s, "a finite time >= 0 s")
    period = 1.0 / rate
    pole = math.exp(-period / time_constant_s) if time_constant_s > 0 else 0.0
    total = -math.expm1(-2.0 * math.pi * bandwidth * period) / (gain * (1.0 - pole))
    return PllGains(total * pole, total * (1.0 - pole) / period)


@dataclasses.dataclass(frozen=True)
class PllState:
    """The PLL between samples (SI).

    Attributes
    ----------
    drive_frequency_hz : float
        f_k, the drive frequency applied until the next sample [Hz].
    integrator_hz : float
        I_k [Hz], the integral part of the frequency offset from the centre.
    phase_error_rad : float
        e_k, the last measured phase error [rad].
    lock_count : int
        Samples in a row with |e| below the threshold (capped at lock_samples).
    locked : bool
        Lock detector output.
    """

    drive_frequency_hz: float
    integrator_hz: float = 0.0
    phase_error_rad: float = 0.0
    lock_count: int = 0
    locked: bool = False


@dataclasses.dataclass(frozen=True)
class PhaseLockedLoop:
    """The digital PLL; :meth:`step` is a pure function ``(state, envelope) -> next state``.

    Parameters
    ----------
    centre_frequency_hz : float
        f_0 [Hz]: the start and, when disabled, the fixed drive frequency.
    gains : PllGains
        From :func:`design_gains` (or :meth:`designed`).
    sample_rate_hz : float
        1/T [Hz].
    lock_threshold_rad : float
        |e| below this counts towards lock [rad], in (0, pi/2).
    lock_samples : int
        Samples in a row to declare lock (>= 1).
    pull_range_hz : float, optional
        The drive frequency stays within f_0 +- pull_range_hz; default 1 % of f_0.
    enabled : bool
        False: the drive frequency stays at f_0 (fixed-frequency drive); the phase error is still
        measured, ``locked`` stays False.
    min_amplitude_m : float
        Below this |A| [m] the phase is not measurable: the loop holds its frequency, e = 0, unlocked.
    """

    centre_frequency_hz: float
    gains: PllGains
    sample_rate_hz: float = PLL_RATE_HZ
    lock_threshold_rad: float = LOCK_THRESHOLD_RAD
    lock_samples: int = LOCK_SAMPLES
    pull_range_hz: float | None = None
    enabled: bool = True
    min_amplitude_m: float = MIN_AMPLITUDE_M

    def __post_init__(self) -> None:
        centre = require_positive("centre_frequency_hz", self.centre_frequency_hz)
        object.__setattr__(self, "centre_frequency_hz", centre)
        if not isinstance(self.gains, PllGains):
            raise InvalidParameterError("gains", type(self.gains).__name__, "a PllGains")
        for name in ("proportional_hz_per_rad", "integral_hz_per_rad_s"):
            value = getattr(self.gains, name)
            if not (math.isfinite(value) and value >= 0):
                raise InvalidParameterError(f"gains.{name}", value, "finite and >= 0")
        object.__setattr__(self, "sample_rate_hz", require_positive("sample_rate_hz", self.sample_rate_hz))
        threshold = require_positive("lock_threshold_rad", self.lock_threshold_rad)
        if threshold >= math.pi / 2:
            raise InvalidParameterError("lock_threshold_rad", self.lock_threshold_rad, "in (0, pi/2) rad")
        object.__setattr__(self, "lock_threshold_rad", threshold)
        if isinstance(self.lock_samples, bool) or not isinstance(self.lock_samples, (int, np.integer)) \
                or self.lock_samples < 1:
            raise InvalidParameterError("lock_samples", self.lock_samples, "a whole number >= 1")
        object.__setattr__(self, "lock_samples", int(self.lock_samples))
        pull = centre * PULL_RANGE_FRACTION if self.pull_range_hz is None else self.pull_range_hz
        pull = require_positive("pull_range_hz", pull)
        if pull >= centre:
            raise InvalidParameterError("pull_range_hz", self.pull_range_hz,
                                        f"below the centre frequency {centre:g} Hz")
        object.__setattr__(self, "pull_range_hz", pull)
        if not isinstance(self.enabled, (bool, np.bool_)):
            raise InvalidParameterError("enabled", self.enabled, "True or False")
        object.__setattr__(self, "min_amplitude_m", require_positive("min_amplitude_m", self.min_amplitude_m))

    @classmethod
    def designed(cls, transducer: Transducer, *, bandwidth_hz: float = PLL_BANDWIDTH_HZ,
                 sample_rate_hz: float = PLL_RATE_HZ, quasi_static: bool = False, **options) -> PhaseLockedLoop:
        """A PLL centred on ``transducer``'s nominal resonance with gains (P2) for ``bandwidth_hz`` [Hz].

        ``quasi_static`` designs for the quasi-static transducer (tau = 0); ``options`` go to the constructor.
        """
        tau = 0.0 if quasi_static else transducer.time_constant_s()
        gains = design_gains(bandwidth_hz, sample_rate_hz, transducer.phase_gain_rad_per_hz, tau)
        return cls(transducer.resonance_frequency_hz, gains, sample_rate_hz, **options)

    @property
    def period_s(self) -> float:
        return 1.0 / self.sample_rate_hz

    def initial_state(self) -> PllState:
        """At the centre frequency, integrator empty, unlocked."""
        return PllState(self.centre_frequency_hz)

    def step(self, state: PllState, envelope_m: complex) -> PllState:
        """One sample: the envelope A_k [m] measured now (relative to the drive) -> the next state (f_k, ...)."""
        if not isinstance(state, PllState):
            raise InvalidParameterError("state", type(state).__name__, "a PllState")
        envelope = complex(envelope_m)
        if not cmath.isfinite(envelope):
            raise InvalidParameterError("envelope_m", envelope_m, "a finite complex amplitude [m]")
        frequency, integrator, error, count, locked = tracker_kernels.pll_sample(
            envelope.real, envelope.imag, state.drive_frequency_hz, state.integrator_hz, state.lock_count,
            state.locked, *self.constants)
        return PllState(float(frequency), float(integrator), float(error), int(count), bool(locked))

    @functools.cached_property
    def constants(self) -> tuple:
        """What :func:`~nfal.models.tracker_kernels.pll_sample` takes after the state: centre frequency, gains,
        period, pull range, lock threshold and samples, least amplitude, enabled."""
        return (self.centre_frequency_hz, self.gains.proportional_hz_per_rad, self.gains.integral_hz_per_rad_s,
                self.period_s, self.pull_range_hz, self.lock_threshold_rad, self.lock_samples, self.min_amplitude_m,
                bool(self.enabled))


@dataclasses.dataclass(frozen=True)
class TrackerState:
    """Transducer envelope A [m] (relative to the drive) and the PLL's state."""

    envelope_m: complex
    pll: PllState


@dataclasses.dataclass(frozen=True)
class TrackerOutputs:
    """What the ResonanceTracker FMU outputs (SI)."""

    excitation_amplitude_m: float
    drive_frequency_hz: float
    locked: bool
    phase_error_rad: float


class ResonanceTracker:
    """Transducer + PLL, the resonance-tracking block of Fig. 7, as pure output/update functions.

    At a PLL sample instant the PLL measures the envelope as it is at that instant (dynamic mode: the state;
    quasi-static mode: (T3) at the current voltage and the frequency applied so far) and sets the new drive
    frequency; the outputs are then the amplitude the plant sees from that instant on (dynamic: |A|, which is
    continuous; quasi-static: |(T3)| at the new frequency). :meth:`advance` commits the sample and integrates
    the envelope exactly (T4) over the step with the new frequency and the inputs held.

    Parameters
    ----------
    transducer : Transducer
    pll : PhaseLockedLoop
    dynamics : bool
        True: the envelope ODE (T2); False: quasi-static (T3).
    """

    def __init__(self, transducer: Transducer, pll: PhaseLockedLoop, *, dynamics: bool = True) -> None:
        if not isinstance(transducer, Transducer):
            raise InvalidParameterError("transducer", type(transducer).__name__, "a Transducer")
        if not isinstance(pll, PhaseLockedLoop):
            raise InvalidParameterError("pll", type(pll).__name__, "a PhaseLockedLoop")
        self.transducer, self.pll, self.dynamics = transducer, pll, bool(dynamics)
        self._last_sample: tuple | None = None  # (state, inputs, the PLL's next state): outputs(), then advance()

    def initial_state(self, voltage_v: float = 0.0, resonance_shift_hz: float = 0.0) -> TrackerState:
        """Steady state (T3) at the centre frequency for the initial inputs (a bumpless start)."""
        pll = self.pll.initial_state()
        return TrackerState(self.transducer.steady_state(voltage_v, pll.drive_frequency_hz, resonance_shift_hz), pll)

    def _sampled(self, state: TrackerState, voltage_v: float, resonance_shift_hz: float, at_sample: bool) -> PllState:
        if not isinstance(state, TrackerState):
            raise InvalidParameterError("state", type(state).__name__, "a TrackerState")
        if not at_sample:
            return state.pll
        inputs = None if self.dynamics else (voltage_v, resonance_shift_hz)  # what the sample measures besides state
        last = self._last_sample
        if last is not None and last[0] is state and last[1] == inputs:
            return last[2]  # the states are immutable: the sample outputs() took is the one advance() commits
        measured = state.envelope_m if self.dynamics else \
            self.transducer.steady_state(voltage_v, state.pll.drive_frequency_hz, resonance_shift_hz)
        pll = self.pll.step(state.pll, measured)
        self._last_sample = (state, inputs, pll)
        return pll

    def _envelope(self, state: TrackerState, pll: PllState, voltage_v: float, resonance_shift_hz: float) -> complex:
        if self.dynamics:
            return state.envelope_m
        return self.transducer.steady_state(voltage_v, pll.drive_frequency_hz, resonance_shift_hz)

    def outputs(self, state: TrackerState, voltage_v: float, resonance_shift_hz: float, *,
                at_sample: bool) -> TrackerOutputs:
        """The outputs at a communication point from the state and the inputs set there (no commit)."""
        pll = self._sampled(state, voltage_v, resonance_shift_hz, at_sample)
        envelope = self._envelope(state, pll, voltage_v, resonance_shift_hz)
        return TrackerOutputs(abs(envelope), pll.drive_frequency_hz, pll.locked, pll.phase_error_rad)

    def advance(self, state: TrackerState, voltage_v: float, resonance_shift_hz: float, dt_s: float, *,
                at_sample: bool) -> TrackerState:
        """Commit the sample (if ``at_sample``) and integrate over ``dt_s`` [s] with the inputs held."""
        pll = self._sampled(state, voltage_v, resonance_shift_hz, at_sample)
        if self.dynamics:
            envelope = self.transducer.step(state.envelope_m, voltage_v, pll.drive_frequency_hz,
                                            resonance_shift_hz, dt_s)
        else:
            require_positive("dt_s", dt_s)
            envelope = self.transducer.steady_state(voltage_v, pll.drive_frequency_hz, resonance_shift_hz)
        return TrackerState(envelope, pll)


@dataclasses.dataclass(frozen=True)
class TrackingRun:
    """A simulated run of :func:`simulate_tracking`, one row per step (SI)."""

    time_s: np.ndarray
    resonance_shift_hz: np.ndarray
    excitation_amplitude_m: np.ndarray
    drive_frequency_hz: np.ndarray
    phase_error_rad: np.ndarray
    locked: np.ndarray


def drift_ramp(shift_hz: float, ramp_s: float, start_s: float = 0.0) -> Callable[[float], float]:
    """A resonance shift [Hz] that is 0 until ``start_s``, ramps to ``shift_hz`` over ``ramp_s`` [s], then holds."""
    shift = float(shift_hz)
    ramp = require_positive("ramp_s", ramp_s)
    return lambda t: shift * min(max((t - start_s) / ramp, 0.0), 1.0)


def simulate_tracking(tracker: ResonanceTracker, duration_s: float, *, voltage_v: float = 100.0,
                      resonance_shift_hz: Callable[[float], float] | float = 0.0,
                      step_s: float | None = None) -> TrackingRun:
    """Run the tracker alone for ``duration_s`` [s] at constant voltage, the shift a function of time [Hz].

    Communication step ``step_s`` [s] (default the PLL period; it must divide it); the PLL samples every
    whole number of periods, as in the FMU. The state starts at :meth:`ResonanceTracker.initial_state`.
    """
    period = tracker.pll.period_s
    step = period if step_s is None else require_positive("step_s", step_s)
    per_sample = round(period / step)
    if per_sample < 1 or abs(per_sample * step - period) > 1e-9 * period:
        raise InvalidParameterError("step_s", step_s, f"the PLL period {period:g} s divided by a whole number")
    shift = resonance_shift_hz if callable(resonance_shift_hz) else (lambda t: float(resonance_shift_hz))
    steps = int(round(require_positive("duration_s", duration_s) / step))
    time = np.arange(steps) * step
    shifts = np.array([shift(t) for t in time], dtype=float)
    amplitude, frequency, error = np.empty(steps), np.empty(steps), np.empty(steps)
    locked = np.zeros(steps, dtype=bool)
    state = tracker.initial_state(voltage_v, shifts[0])
    for k in range(steps):
        at_sample = k % per_sample == 0
        out = tracker.outputs(state, voltage_v, shifts[k], at_sample=at_sample)
        amplitude[k], frequency[k], error[k], locked[k] = (out.excitation_amplitude_m, out.drive_frequency_hz,
                                                           out.phase_error_rad, out.locked)
        state = tracker.advance(state, voltage_v, shifts[k], step, at_sample=at_sample)
    logger.info("tracked the resonance for %d steps (PLL %s)", steps, "on" if tracker.pll.enabled else "off")
    return TrackingRun(time, shifts, amplitude, frequency, error, locked)
