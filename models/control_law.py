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

Five additions the paper does not have, each off unless asked for (the Controller FMU asks for lift-off, the lead
and the reference zero; the Reynolds loop for the feedforward path; docs/controller.md, "Beyond the paper's law"):

* **Reference zero.** Pole placement leaves the PI zero at tau_PI = k_p / k_i where it falls, slower than the slow
  double pole 1 / p1 at small gaps (1.6 / p1 at 60 um in the blind sampled design): a step then overshoots by
  (r - 1) e^(-r / (r - 1)), r = p1 tau_PI, 4 % at 60 um, whatever the poles. With ``reference_zero_ratio`` = rho
  the reference passes through (1 + b tau_PI s) / (1 + tau_PI s), b = min(1, rho / (p1 tau_PI)) at the gains of
  this sample: the filter's pole cancels the PI zero (exactly, in the forward-Euler law) and its zero takes the
  place at rho / p1 (rho = 1: it cancels one of the slow pair, and the linear loop's steps cannot overshoot).
  For given gains the loop, its noise and its disturbance rejection are unchanged; at an equilibrium the filter
  is the identity. (The sampled placement reaches its cut-off through the filter, :mod:`.sampled_design`, which
  does change the gains.)
* **Reference pair.** The law follows the reference through a critically damped pair of time constant
  ``reference_filter_s`` (a two-degree-of-freedom PID: the loop's poles are unchanged, the steps are
  smoothed): less overshoot for a larger IAE (10 ms, without the reference zero: overshoot 6.5 -> 3.0 %,
  IAE 4.2 -> 8.6 um s).
* **Lift-off.** A rig starts with the object at rest on the surface, far below the work range; a step from
  there to the first reference lifts it violently (peaks near 100 um for a 60 um reference, the film's
  force growing as (a/h)^2 near the surface). When the first sample measures a clearance below the work
  range, the law starts from no excitation and follows the reference through the pair with the slower
  time constant ``lift_off_time_s``, started at that clearance, until it is within 0.1 % of the reference.
* **Feedforward path.** With ``feedforward`` (the design model, eq. 13) and ``reference_filter_s`` = tau, the
  law follows a path instead of the reference: a critically damped pair of time constant tau whose acceleration is
  limited to what the model reaches with a drive between ``FEEDFORWARD_FLOOR`` times the holding drive and
  ``FEEDFORWARD_CEILING`` times |a|_max; the drive the model needs along it (eq. 13 solved for u) enters the
  integrator as it changes, and the derivative acts on the path's velocity less the measured rate. Where the film's
  K falls steeply (a 100 -> 60 um step of the Fig. 3 stand-in's film drove |a| to 0 for 25 ms and overshot 16 %)
  the step then follows what the film can do: 1.4 %.
* **Actuator lag.** The transducer's amplitude follows the commanded one with the time constant
  tau = 2 Q / omega_r (5.6 ms, :mod:`.transducer`), a lag the design of eq. (23) does not see. With
  ``actuator_lag_s`` = tau the clamped command passes through the lead (1 + tau s) / (1 + tau s / N),
  N = ``LEAD_RATIO`` (backward Euler), and is clamped again: the lag is cancelled up to N / tau.
"""

from __future__ import annotations

import dataclasses
import math

from nfal.errors import InvalidParameterError, require_positive, span_um

from .pid_design import FixedGains, GainSchedule
from .plant import SimplifiedPlant
from .plausibility import MAX_EXCITATION_M as PLAUSIBLE_EXCITATION_M
from .plausibility import MAX_SHAPING_TIME_S, require_plausible
from .table2 import MAX_EXCITATION_M, SAMPLING_RATE_HZ, WORK_RANGE_M

#: A drive saturated at the limit this long [s] is reported: the reference is out of the film's reach.
SATURATION_WARNING_S = 0.1
#: Accepted measurements [m]: a clearance between touchdown and 1 mm (the sensor's span; assumed).
MEASUREMENT_RANGE_M = (0.0, 1e-3)
#: The lift-off pair's time constant [s]: from rest at 5 um within 1 um of 60 um in ~0.34 s, passing it by
#: < 0.1 um, in simulation and against the emulator (40 ms: 61 um simulated, 68 um in HIL; docs/controller.md).
LIFT_OFF_TIME_S = 0.06
#: Lift-off ends when the pair is this close to the reference (relative).
LIFT_OFF_END = 1e-3
#: The feedforward's path asks the design model for at least this fraction of the drive that holds its clearance,
#: and at most this fraction of |a|_max: the rest is the feedback's room.
FEEDFORWARD_FLOOR, FEEDFORWARD_CEILING = 0.5, 0.9
#: High-frequency gain N of the actuator-lag lead (1 + tau s) / (1 + tau s / N).
LEAD_RATIO = 4.0
#: A saturation goes on through dips below the limit shorter than this [s] (measurement noise feeds through).
SATURATION_GAP_S = 0.02


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
    reference_pair_m : (float, float) or None
        The reference pair's two states [m]; None where the reference is used as given.
    lifting : bool
        Lifting off (the pair runs with the lift-off time constant).
    reference_lag_m : float or None
        The reference zero's filter state [m]; None where it is off.
    feedforward_m : float or None
        The model feedforward of the last sample [m of excitation]; None where none was given.
    reference_model_m : (float, float) or None
        The path the feedforward follows: clearance [m] and velocity [m/s]; None where there is none.
    lead_m : (float, float) or None
        The actuator-lag lead's last input and output [m]; None before the first sample.
    """

    integrator_m: float
    derivative_m_per_s: float = 0.0
    previous_measurement_m: float | None = None
    reference_pair_m: tuple[float, float] | None = None
    lead_m: tuple[float, float] | None = None
    lifting: bool = False
    reference_lag_m: float | None = None
    feedforward_m: float | None = None
    reference_model_m: tuple[float, float] | None = None

    def as_list(self) -> list:
        """The state as JSON-able numbers (an FMU state); :meth:`from_list` reads it back."""
        return [list(value) if isinstance(value, tuple) else value for value in dataclasses.astuple(self)]

    @classmethod
    def from_list(cls, values: list) -> ControllerState:
        """Read :meth:`as_list` back; a shorter list (a state saved by an earlier version) leaves the rest default."""
        def read(value):
            if isinstance(value, (list, tuple)):
                return tuple(float(v) for v in value)
            return value if value is None or isinstance(value, bool) else float(value)

        return cls(**{field.name: read(value) for field, value in zip(dataclasses.fields(cls), values)})


@dataclasses.dataclass
class SaturationWatch:
    """How long the command has been at the limit ``limit_m``, through dips shorter than SATURATION_GAP_S: the episodes
    the Controller FMU reports (``saturated_time``, a warning once per episode) and a loop that runs its law elsewhere
    records alike."""

    limit_m: float
    since_s: float | None = None  #: start of the current saturation, if any
    last_at_limit_s: float = 0.0  #: the last sample at the limit
    warned: bool = False          #: the current saturation has been reported

    def update(self, now_s: float, command_m: float) -> None:
        """The command held from ``now_s`` on."""
        if command_m >= self.limit_m:
            if self.since_s is None:
                self.since_s = now_s
            self.last_at_limit_s = now_s
        elif self.since_s is not None and now_s - self.last_at_limit_s > SATURATION_GAP_S:
            self.since_s, self.warned = None, False

    def warning_due(self, now_s: float, warning_time_s: float) -> bool:
        """True once per saturation, when it has lasted ``warning_time_s``."""
        if self.since_s is None or self.warned or now_s - self.since_s < warning_time_s - 1e-12:
            return False
        self.warned = True
        return True

    def duration_s(self, now_s: float) -> float:
        """How long the current saturation has lasted at ``now_s`` (0: none)."""
        return 0.0 if self.since_s is None else max(0.0, now_s - self.since_s)


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
    reference_filter_s : float, optional
        Time constant [s] of the reference pair (see the module docstring); None: the reference as given.
    lift_off_time_s : float, optional
        Time constant [s] of the pair while lifting off (see the module docstring); None: no lift-off mode.
    actuator_lag_s : float
        The actuator's lag tau [s] the lead cancels (see the module docstring); 0: no lead.
    reference_zero_ratio : float, optional
        rho, where the reference's zero goes in slow-pole time constants (see the module docstring); None: the
        design's PI zero acts on the reference as in the paper.
    feedforward : SimplifiedPlant, optional
        The design model whose inverse gives the drive the reference pair's path needs (see the module docstring;
        needs ``reference_filter_s``; the reference zero then stays off). None: no feedforward.
    """

    def __init__(self, gains: GainSchedule | FixedGains, *, sample_rate_hz: float = SAMPLING_RATE_HZ,
                 max_excitation_m: float = MAX_EXCITATION_M, tracking_time_s: float | None = None,
                 reference_range_m: tuple[float, float] = WORK_RANGE_M, reference_filter_s: float | None = None,
                 lift_off_time_s: float | None = None, actuator_lag_s: float = 0.0,
                 reference_zero_ratio: float | None = None, feedforward: SimplifiedPlant | None = None) -> None:
        if not isinstance(gains, (GainSchedule, FixedGains)):
            raise InvalidParameterError("gains", type(gains).__name__, "a GainSchedule or FixedGains")
        self.gains = gains
        self.sample_rate_hz = require_positive("sample_rate_hz", sample_rate_hz)
        self.period_s = 1.0 / self.sample_rate_hz
        self.max_excitation_m = require_plausible("max_excitation_m",
                                                  require_positive("max_excitation_m", max_excitation_m),
                                                  PLAUSIBLE_EXCITATION_M, "m")
        self.tracking_time_s = (self.period_s if tracking_time_s is None
                                else require_positive("tracking_time_s", tracking_time_s))
        low, high = (float(v) for v in reference_range_m)
        if not (0.0 < low <= high < math.inf):
            raise InvalidParameterError("reference_range_m", reference_range_m, "0 < low <= high, finite [m]")
        self.reference_range_m = (low, high)
        self.reference_filter_s, self.lift_off_time_s = (
            None if value is None else require_plausible(name, require_positive(name, value), MAX_SHAPING_TIME_S, "s")
            for name, value in (("reference_filter_s", reference_filter_s), ("lift_off_time_s", lift_off_time_s)))
        self.actuator_lag_s = float(actuator_lag_s)
        self.reference_zero_ratio = (None if reference_zero_ratio is None
                                     else require_positive("reference_zero_ratio", reference_zero_ratio))
        unusable = self.reference_filter_s is None or not isinstance(feedforward, SimplifiedPlant)
        if feedforward is not None and unusable:
            raise InvalidParameterError("feedforward", feedforward, "a SimplifiedPlant, with reference_filter_s (a "
                                        "step of the reference has no finite acceleration to feed forward)")
        self.feedforward = feedforward
        if not (math.isfinite(self.actuator_lag_s) and 0.0 <= self.actuator_lag_s < 1.0):
            raise InvalidParameterError("actuator_lag_s", actuator_lag_s, "a finite lag >= 0 and < 1 s")
        # per-sample constants of the pair (decay over one period) and of the lead (backward Euler weights)
        self._decay = {lifting: None if tc is None else math.exp(-self.period_s / tc)
                       for lifting, tc in ((True, self.lift_off_time_s), (False, self.reference_filter_s))}
        fast = self.actuator_lag_s / LEAD_RATIO
        self._lead_weights = (fast / (fast + self.period_s), self.period_s / (fast + self.period_s),
                              self.actuator_lag_s / (fast + self.period_s))
        self.filter_rad_s = gains.omega_lpf * gains.omega  # omega_L [rad/s]
        if self.period_s * self.filter_rad_s >= 2.0:
            raise InvalidParameterError("sample_rate_hz", sample_rate_hz,
                                        f"> {self.filter_rad_s / 2:.4g} Hz so that forward Euler of the filter "
                                        "is stable")
        self.name = gains.name

    def compiled_constants(self) -> dict:
        """Everything :meth:`step` computes from besides its arguments, as ``firmware/loop/nfal_law.h``'s
        ``nfal_law_params`` names it (the compiled loop's law). A law with a feedforward path is refused: the
        compiled law does not carry the design model."""
        if self.feedforward is not None:
            raise InvalidParameterError("feedforward", self.feedforward, "none: the compiled loop's law has no "
                                        "feedforward path (run this law in the Python loop)")
        decays = {name: (0 if decay is None else 1, 0.0 if decay is None else decay)
                  for name, decay in (("reference_pair", self._decay[False]), ("lift_off", self._decay[True]))}
        return {"period_s": self.period_s, "filter_rad_s": self.filter_rad_s,
                "max_excitation_m": self.max_excitation_m, "tracking_time_s": self.tracking_time_s,
                "reference_low_m": self.reference_range_m[0], "reference_high_m": self.reference_range_m[1],
                "measurement_low_m": MEASUREMENT_RANGE_M[0], "measurement_high_m": MEASUREMENT_RANGE_M[1],
                **{key: value for name, (has, decay) in decays.items()
                   for key, value in ((f"has_{name}", has), (f"{name}_decay", decay))},
                "has_lead": int(self.actuator_lag_s != 0.0),
                **dict(zip(("lead_held", "lead_new", "lead_rate"), self._lead_weights)),
                "has_reference_zero": int(self.reference_zero_ratio is not None),
                "reference_zero_ratio": self.reference_zero_ratio or 0.0, **self.gains.law_table()}

    def initial_state(self, height_m: float, excitation_m: float) -> ControllerState:
        """Bumpless start at an equilibrium: the integrator holds the excitation ``excitation_m`` [m] that holds
        ``height_m`` [m], and the first sample's derivative update is zero whatever it measures, so a plant that
        starts elsewhere (a rig's object at rest on the surface) gets no derivative kick."""
        height = self._check("height_m", height_m, MEASUREMENT_RANGE_M)
        excitation = self._check("excitation_m", excitation_m, (0.0, self.max_excitation_m))
        return ControllerState(excitation, 0.0, None, reference_lag_m=height)

    def step(self, state: ControllerState, reference_m: float, measured_m: float) -> tuple[float, ControllerState]:
        """One sample: ``(state, reference [m], measured clearance [m]) -> (excitation |a| [m], next state)``."""
        reference = self._check("reference_m", reference_m, self.reference_range_m)
        measured = self._check("measured_m", measured_m, MEASUREMENT_RANGE_M)
        if not isinstance(state, ControllerState):
            raise InvalidParameterError("state", type(state).__name__, "a ControllerState")
        if (state.previous_measurement_m is None and self.lift_off_time_s is not None
                and measured < self.reference_range_m[0]):  # at rest below the work range: lift off from nothing
            state = ControllerState(0.0, reference_pair_m=(measured, measured), lifting=True)
        feedforward = path = None
        if self.feedforward is not None and not state.lifting:  # the path takes the reference pair's place
            start = state.reference_pair_m[1] if state.reference_pair_m else reference  # lifted off, or bumpless
            path, feedforward = self._reference_path(state.reference_model_m or (start, 0.0), reference)
            target, pair, lifting = path[0], None, False
        else:
            target, pair, lifting = self._shaped_reference(state, reference)
        previous = measured if state.previous_measurement_m is None else state.previous_measurement_m
        ts, wl = self.period_s, self.filter_rad_s
        rate = (1.0 - ts * wl) * state.derivative_m_per_s + wl * (measured - previous)
        kp, ki, kd, slow_time = self.gains.law_terms(measured)
        if feedforward is None:
            target, reference_lag = self._weighted_reference(state.reference_lag_m, target, measured, kp, ki,
                                                             slow_time)
        else:
            reference_lag = None
        # the feedforward's change enters the integrator, which holds the drive: bumpless when it starts or stops
        integrator = state.integrator_m + (0.0 if feedforward is None or state.feedforward_m is None
                                           else feedforward - state.feedforward_m)
        error = target - measured
        # with a path, the derivative acts on its velocity less the measured rate: the feedback does not brake the
        # motion the feedforward asks for
        unsaturated = kp * error + integrator - kd * (rate - (0.0 if path is None else path[1]))
        command = min(max(unsaturated, 0.0), self.max_excitation_m)
        integrator += ts * ki * error + (ts / self.tracking_time_s) * (command - unsaturated)
        output, lead = self._lead(state.lead_m, command)
        following = None if path is None else self._advance_path(path)
        return output, ControllerState(float(integrator), float(rate), measured, pair, lead, lifting, reference_lag,
                                       feedforward, following)

    def _reference_path(self, path: tuple[float, float], reference: float) -> tuple[tuple, float | None]:
        """This sample's point of the path the feedforward follows, (clearance, velocity, acceleration), and the
        drive [m] the design model needs there (None where its film does not push).

        The path is a critically damped pair of time constant ``reference_filter_s`` towards the reference, its
        acceleration limited to what the model reaches with a drive between FEEDFORWARD_FLOOR times the drive
        that holds the path's clearance and FEEDFORWARD_CEILING times |a|_max: a path the plant can follow with
        room left for the feedback, so a large step does not saturate the drive (the film lets the object fall
        no faster than its damping allows)."""
        height, velocity = path
        tau, film = self.reference_filter_s, self.feedforward.local_film(height)
        acceleration = (reference - height) / tau**2 - 2.0 * velocity / tau
        holding = film.excitation(0.0, 0.0)
        if holding is None:
            return (height, velocity, acceleration), None
        low = film.acceleration(velocity, FEEDFORWARD_FLOOR * holding)
        high = film.acceleration(velocity, FEEDFORWARD_CEILING * self.max_excitation_m)
        acceleration = min(max(acceleration, low), max(low, high))
        return (height, velocity, acceleration), min(film.excitation(velocity, acceleration), self.max_excitation_m)

    def _advance_path(self, point: tuple[float, float, float]) -> tuple[float, float]:
        """The path's next (clearance, velocity): semi-implicit Euler over one period."""
        height, velocity, acceleration = point
        velocity += self.period_s * acceleration
        return float(height + self.period_s * velocity), float(velocity)

    def _weighted_reference(self, lag: float | None, target: float, measured: float, kp: float, ki: float,
                            slow_time: float):
        """The reference through (1 + b tau_PI s) / (1 + tau_PI s): its pole cancels the PI zero at
        tau_PI = k_p / k_i (in the forward-Euler law, exactly), its zero lies at ``reference_zero_ratio``
        times the slow pole's time constant (b <= 1: never slower than the PI zero it replaces). The filter's
        next state."""
        if self.reference_zero_ratio is None or ki <= 0.0:
            return target, None
        pi_time = kp / ki
        weight = min(1.0, self.reference_zero_ratio * slow_time / pi_time)
        decay = max(0.0, 1.0 - self.period_s / pi_time)
        lag = decay * (measured if lag is None else lag) + (1.0 - decay) * target
        return weight * target + (1.0 - weight) * lag, float(lag)

    def _shaped_reference(self, state: ControllerState, reference: float) -> tuple[float, tuple | None, bool]:
        """The reference this sample follows, the pair's next state and whether lift-off goes on."""
        lifting = state.lifting
        decay = self._decay[lifting]
        if decay is None:
            return reference, None, False
        first, second = state.reference_pair_m or (reference, reference)
        first = reference + (first - reference) * decay
        second = first + (second - first) * decay
        if lifting and abs(reference - second) <= LIFT_OFF_END * reference:
            lifting = False  # lifted off: from the next sample on, the steps' pair (or the reference as given)
        return second, ((first, second) if lifting or self.reference_filter_s is not None else None), lifting

    def _lead(self, lead: tuple[float, float] | None, command: float) -> tuple[float, tuple | None]:
        """The clamped command through the actuator-lag lead, clamped again; the lead's next state."""
        if self.actuator_lag_s == 0.0:
            return command, None
        last_input, last_output = (command, command) if lead is None else lead
        held, new, rate = self._lead_weights
        output = held * last_output + new * command + rate * (command - last_input)
        return min(max(output, 0.0), self.max_excitation_m), (command, float(output))

    @staticmethod
    def _check(name: str, value, allowed: tuple[float, float]) -> float:
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise InvalidParameterError(name, value, "a finite number [m]") from None
        if not (math.isfinite(number) and allowed[0] <= number <= allowed[1]):
            raise InvalidParameterError(name, value, f"finite and within {span_um(*allowed)}")
        return number
