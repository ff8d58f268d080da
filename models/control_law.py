"""The discrete gain-scheduled PID of eqs. (21)-(22): one sample at a time, with saturation and anti-windup.

Per sample k (period T_s, measured clearance h_k, reference r_k, gains at the scheduling variable h_k):

    psi_k  = (1 - T_s omega_L) psi_{k-1} + omega_L (h_k - h_{k-1})      filtered derivative of the
                                                                         measurement, eq. (22), forward Euler
    v_k    = k_p (r_k - h_k) + eta_k - k_d psi_k                         eq. (21)
    a_k    = min(max(v_k, 0), a_max)                                     actuator saturation
    eta_{k+1} = eta_k + T_s k_i (r_k - h_k) + (T_s / T_t) (a_k - v_k)    eq. (22) forward Euler, plus
                                                                         back-calculation anti-windup

This is forward Euler of eqs. (21)-(22) in T = omega t with step omega T_s, written in SI (k_p [m/m],
k_i [1/s], k_d [s], eta [m], psi [m/s]): the scaling is linear, so the samples are identical. The
scheduled gains multiply only the error and psi, both zero at an equilibrium, and k_i sits inside the
integral (the velocity algorithm of Kaminer et al.), so the law linearised about any equilibrium is the
linear PID designed there: no hidden coupling terms. With T_t = T_s (the default) the back-calculation
resets eta every saturated sample so that v equals the applied a: the law then behaves as the
incremental (velocity-form) PID whose accumulated output is clamped.
"""

from __future__ import annotations

import dataclasses
import math


from .errors import InvalidParameterError, require_positive
from .plausibility import MAX_EXCITATION_M as PLAUSIBLE_EXCITATION_M
from .plausibility import require_plausible
from .pid_design import SAMPLING_RATE_HZ, WORK_RANGE_M, FixedGains, GainSchedule

#: Default actuator limit |a|_max [m]: 1.6 x the 6.2 um the paper's rig needs to hold 200 um (eq. 16),
#: above the 7 um of Table 1's curve (a); not given by the paper.
MAX_EXCITATION_M = 10e-6
#: A drive saturated at the limit this long [s] is reported: the reference is out of the film's reach.
SATURATION_WARNING_S = 0.1
#: Accepted measurements [m]: a clearance between touchdown and 1 mm (the sensor's span; assumed).
MEASUREMENT_RANGE_M = (0.0, 1e-3)


@dataclasses.dataclass(frozen=True)
class ControllerState:
    """The law's memory between samples (SI).

    Attributes
    ----------
    integrator_m : float
        eta of eq. (22) [m of excitation].
    derivative_m_per_s : float
        psi of eq. (22): the filtered rate of the measured clearance [m/s].
    previous_measurement_m : float or None
        h_{k-1} [m]; None before the first sample (the first derivative update is then zero).
    """

    integrator_m: float
    derivative_m_per_s: float = 0.0
    previous_measurement_m: float | None = None


class DiscreteControlLaw:
    """Eqs. (21)-(22) at a fixed sampling rate; :meth:`step` is a pure function of its arguments.

    Parameters
    ----------
    gains : GainSchedule or FixedGains
        The scheduled gains (gain-scheduled controller) or one design's gains (linear controller).
    sample_rate_hz : float
        Sampling rate [Hz] (Table 2: 2000).
    max_excitation_m : float
        Actuator limit |a|_max [m]; the command is clamped to [0, |a|_max].
    tracking_time_s : float, optional
        Back-calculation time constant T_t [s]; default one sample period.
    reference_range_m : (float, float)
        Accepted references [m] (default the work range 50-200 um).
    """

    def __init__(self, gains: GainSchedule | FixedGains, *, sample_rate_hz: float = SAMPLING_RATE_HZ,
                 max_excitation_m: float = MAX_EXCITATION_M, tracking_time_s: float | None = None,
                 reference_range_m: tuple[float, float] = WORK_RANGE_M) -> None:
        if not isinstance(gains, (GainSchedule, FixedGains)):
            raise InvalidParameterError("gains", type(gains).__name__, "a GainSchedule or FixedGains")
        self.gains = gains
        self.sample_rate_hz = require_positive("sample_rate_hz", sample_rate_hz)
        self.period_s = 1.0 / self.sample_rate_hz
        self.max_excitation_m = require_plausible("max_excitation_m", require_positive("max_excitation_m", max_excitation_m),
                                                  PLAUSIBLE_EXCITATION_M, "m")
        self.tracking_time_s = self.period_s if tracking_time_s is None else require_positive("tracking_time_s", tracking_time_s)
        low, high = (float(v) for v in reference_range_m)
        if not (0.0 < low <= high < math.inf):
            raise InvalidParameterError("reference_range_m", reference_range_m, "0 < low <= high, finite [m]")
        self.reference_range_m = (low, high)
        self.filter_rad_s = gains.omega_lpf * gains.omega  # omega_L [rad/s]
        if self.period_s * self.filter_rad_s >= 2.0:
            raise InvalidParameterError("sample_rate_hz", sample_rate_hz,
                                        f"> {self.filter_rad_s / 2:.4g} Hz so that forward Euler of the filter is stable")
        self.name = gains.name

    def initial_state(self, height_m: float, excitation_m: float) -> ControllerState:
        """Bumpless start at an equilibrium: the integrator holds the excitation ``excitation_m`` [m] that holds
        ``height_m`` [m], and the first sample's derivative update is zero whatever it measures, so a plant that
        starts elsewhere (a rig's object at rest on the surface) gets no derivative kick."""
        self._check("height_m", height_m, MEASUREMENT_RANGE_M)  # checked only: the state needs the excitation
        excitation = self._check("excitation_m", excitation_m, (0.0, self.max_excitation_m))
        return ControllerState(excitation, 0.0, None)

    def step(self, state: ControllerState, reference_m: float, measured_m: float) -> tuple[float, ControllerState]:
        """One sample: ``(state, reference [m], measured clearance [m]) -> (excitation |a| [m], next state)``."""
        reference = self._check("reference_m", reference_m, self.reference_range_m)
        measured = self._check("measured_m", measured_m, MEASUREMENT_RANGE_M)
        if not isinstance(state, ControllerState):
            raise InvalidParameterError("state", type(state).__name__, "a ControllerState")
        previous = measured if state.previous_measurement_m is None else state.previous_measurement_m
        ts, wl = self.period_s, self.filter_rad_s
        rate = (1.0 - ts * wl) * state.derivative_m_per_s + wl * (measured - previous)
        kp, ki, kd = self.gains.gains_si(measured)
        error = reference - measured
        unsaturated = kp * error + state.integrator_m - kd * rate
        command = min(max(unsaturated, 0.0), self.max_excitation_m)
        integrator = state.integrator_m + ts * ki * error + (ts / self.tracking_time_s) * (command - unsaturated)
        return command, ControllerState(float(integrator), float(rate), measured)

    @staticmethod
    def _check(name: str, value, allowed: tuple[float, float]) -> float:
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise InvalidParameterError(name, value, "a finite number [m]") from None
        if not (math.isfinite(number) and allowed[0] <= number <= allowed[1]):
            raise InvalidParameterError(name, value, f"finite and within [{allowed[0]:g}, {allowed[1]:g}] m")
        return number
