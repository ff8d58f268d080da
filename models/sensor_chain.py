"""The height measurement of Fig. 7: laser triangulation sensor, noise, analog low-pass, sampling, quantisation.

    u(t)  = h(t) + n_k                        true clearance [m] (held over a communication step) plus the
                                              coloured noise sample n_k drawn at the latest sample instant t_k
                                              (models/measurement_noise.py, held until the next one)
    y'' + sqrt(2) omega_c y' + omega_c^2 y = omega_c^2 u      analog 2nd-order Butterworth low-pass at the
                                              cut-off f_c = omega_c / (2 pi) (Table 2: 2000 Hz), unity DC gain
    m_k   = q round(y(t_k) / q)               sampled at t_k (own rate, Table 2: 2000 Hz) and quantised with
                                              resolution q (a mid-tread quantiser; q = 0: none)

The filter is integrated exactly for an input held over the step: with x = (y, y') and x' = F x + g u,
x(t + dt) = Phi x(t) + Gamma u with [[Phi, Gamma], [0, 1]] = expm([[F, g], [0, 0]] dt) (the zero-order-hold
discretisation, exact for the held input, any dt). It starts in steady state at the first clearance. The
filter has no direct feedthrough: y(t_k) is a function of the inputs before t_k. With the filter off
(f_c = 0) the sample is u(t_k) itself, so with q = 0 too, m_k = h(t_k) + n_k: exactly the measurement of
the pure-Python loop (models/closed_loop.py) fed with ``coloured_noise(samples, ...)``.

Between sample instants the measurement holds m_k. The state is explicit (:class:`SensorState`) and the
methods are pure except for the noise generator, which is a stream; its state is part of
:meth:`SensorChain.get_state` / :meth:`SensorChain.set_state` (FMU state save/restore).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import scipy

from nfal.errors import InvalidParameterError, require_finite, require_positive

from . import sensor_core
from .measurement_noise import ColouredNoise
from .plausibility import MAX_CLEARANCE_M, require_plausible
from .table2 import ANALOG_FILTER_CUTOFF_HZ, NOISE_CUTOFF_HZ, NOISE_PEAK_M, SAMPLING_RATE_HZ

#: Relative difference of two step sizes below which the filter's transition matrix is reused.
STEP_TOLERANCE = 1e-9


def _non_negative(name: str, value, unit: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InvalidParameterError(name, value, f"a finite number >= 0 {unit}") from None
    if not (math.isfinite(number) and number >= 0):
        raise InvalidParameterError(name, value, f"a finite number >= 0 {unit}")
    return number


@dataclasses.dataclass(frozen=True)
class SensorState:
    """The chain between steps (SI).

    Attributes
    ----------
    filter_m : tuple of float
        Analog filter state (y [m], y' [m/s]); unused with the filter off.
    noise_m : float
        The noise sample n_k added since the latest sample instant [m].
    measured_m : float
        The held measurement m_k [m].
    """

    filter_m: tuple[float, float]
    noise_m: float
    measured_m: float


class SensorChain:
    """Sensor + noise + analog low-pass + sampling + quantisation.

    Parameters
    ----------
    sample_rate_hz : float
        Sampling rate [Hz] (Table 2: 2000).
    noise_peak_m : float
        Maximal noise magnitude [m] (3 sigma, the clip level; Sec. 4.1: 2e-6); 0: no noise.
    noise_cutoff_hz : float
        Cut-off of the noise's colouring filter [Hz] (Sec. 4.1: 300); below half the sample rate.
    seed : int
        Seed of the noise.
    analog_cutoff_hz : float
        Cut-off of the analog Butterworth low-pass [Hz] (Table 2: 2000); 0: no filter.
    resolution_m : float
        Quantisation step [m]; 0: none.
    """

    def __init__(self, *, sample_rate_hz: float = SAMPLING_RATE_HZ, noise_peak_m: float = NOISE_PEAK_M,
                 noise_cutoff_hz: float = NOISE_CUTOFF_HZ, seed: int = 0,
                 analog_cutoff_hz: float = ANALOG_FILTER_CUTOFF_HZ, resolution_m: float = 0.0) -> None:
        self.sample_rate_hz = require_positive("sample_rate_hz", sample_rate_hz)
        self.noise = ColouredNoise(self.sample_rate_hz, noise_cutoff_hz, noise_peak_m, seed)
        self.analog_cutoff_hz = _non_negative("analog_cutoff_hz", analog_cutoff_hz, "Hz")
        self.resolution_m = require_plausible("resolution_m", _non_negative("resolution_m", resolution_m, "m"),
                                              MAX_CLEARANCE_M, "m")
        omega = 2.0 * math.pi * self.analog_cutoff_hz
        self._dynamics = np.array([[0.0, 1.0, 0.0], [-omega ** 2, -math.sqrt(2.0) * omega, omega ** 2],
                                   [0.0, 0.0, 0.0]])
        self._cache: tuple[float, tuple[float, ...]] | None = None

    @property
    def period_s(self) -> float:
        return 1.0 / self.sample_rate_hz

    @property
    def filtered(self) -> bool:
        return self.analog_cutoff_hz > 0

    # --- pieces ---------------------------------------------------------------------------------------
    def quantise(self, value_m: float) -> float:
        """q round(value / q) [m] (round half to even); the value itself for q = 0."""
        if self.resolution_m == 0:
            return float(value_m)
        return float(self.resolution_m * np.round(value_m / self.resolution_m))

    def frequency_response(self, frequency_hz: float | np.ndarray) -> np.ndarray:
        """The analog filter's H(i 2 pi f) (1 with the filter off)."""
        f = np.asarray(frequency_hz, dtype=float)
        if not self.filtered:
            return np.ones_like(f, dtype=complex)
        s = 1j * f / self.analog_cutoff_hz
        return 1.0 / (s ** 2 + math.sqrt(2.0) * s + 1.0)

    def _transition(self, dt_s: float) -> tuple[float, ...]:
        """The filter's exact discretisation over ``dt_s`` as floats: (phi00, phi01, phi10, phi11, gamma0, gamma1)."""
        # Reused for steps equal within STEP_TOLERANCE: hosts that subtract time points (libcosim) pass
        # 0.0005000000000000004 for 0.5 ms, and recomputing expm every step would cost 10-100x.
        if self._cache is None or abs(self._cache[0] - dt_s) > STEP_TOLERANCE * dt_s:
            exact = scipy.linalg.expm(self._dynamics * dt_s)
            self._cache = (dt_s, tuple(float(v) for v in (*exact[:2, :2].ravel(), *exact[:2, 2])))
        return self._cache[1]

    @property
    def discretisation(self) -> tuple[float, tuple[float, ...]] | None:
        """(step size [s], the filter's discretisation for it) last used, or None."""
        return self._cache

    # --- the model ------------------------------------------------------------------------------------
    def initial_state(self, true_height_m: float) -> SensorState:
        """The filter in steady state at ``true_height_m``; nothing sampled yet (the held value is the height)."""
        height = self._height(true_height_m)
        return SensorState((height, 0.0), 0.0, height)

    def output(self, state: SensorState, true_height_m: float, *, at_sample: bool) -> float:
        """The measurement [m] at a communication point (no commit): sampled now if ``at_sample``, else held."""
        if not isinstance(state, SensorState):
            raise InvalidParameterError("state", type(state).__name__, "a SensorState")
        return self._output(state, self._height(true_height_m), at_sample)

    def filtered_output(self, state: SensorState, *, at_sample: bool) -> float:
        """The measurement [m] behind the analog filter, which reads the state only: :meth:`output` without a height
        to check (the FMU's read of an output of the state, fmus/sensor_chain.py)."""
        if not self.filtered:
            raise InvalidParameterError("analog_cutoff_hz", self.analog_cutoff_hz, "> 0 for a measurement of the state")
        if not isinstance(state, SensorState):
            raise InvalidParameterError("state", type(state).__name__, "a SensorState")
        return self._output(state, math.nan, at_sample)

    def _output(self, state: SensorState, height: float, at_sample: bool) -> float:
        if not at_sample:
            return state.measured_m
        if self.filtered:
            return self.quantise(state.filter_m[0])
        return self.quantise(height + self.noise.peek())

    def advance(self, state: SensorState, true_height_m: float, dt_s: float, *, at_sample: bool) -> SensorState:
        """Commit the sample (drawing the next noise value) if ``at_sample``, then run the filter over ``dt_s``."""
        if not isinstance(state, SensorState):
            raise InvalidParameterError("state", type(state).__name__, "a SensorState")
        height = self._height(true_height_m)
        measured = self._output(state, height, at_sample)
        dt = require_positive("dt_s", dt_s)
        noise = self.noise.next_sample() if at_sample else state.noise_m
        filt = state.filter_m
        if self.filtered:
            filt = sensor_core.filter_step(filt[0], filt[1], height + noise, *self._transition(dt))
        return SensorState(filt, noise, measured)

    def get_state(self, state: SensorState) -> dict:
        """``state`` and the noise generator's state as plain Python types (for FMU state save)."""
        return {"sensor": dataclasses.asdict(state), "noise": self.noise.get_state()}

    def set_state(self, saved: dict) -> SensorState:
        """Restore the noise generator from :meth:`get_state`'s result and return the sensor state."""
        try:
            sensor = saved["sensor"]
            state = SensorState(tuple(float(v) for v in sensor["filter_m"]), float(sensor["noise_m"]),
                                float(sensor["measured_m"]))
            noise = saved["noise"]
        except (KeyError, TypeError, ValueError) as exc:
            raise InvalidParameterError("saved", type(saved).__name__,
                                        f"a state from SensorChain.get_state ({exc})") from None
        self.noise.set_state(noise)
        return state

    @staticmethod
    def _height(value) -> float:
        """The true height, checked: a sensor of a levitation gap does not report 1e300 m."""
        return require_plausible("true_height", require_finite("true_height", value, "a finite clearance [m]"),
                                 MAX_CLEARANCE_M, "m")
