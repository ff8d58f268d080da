"""Controller FMU: the discrete gain-scheduled (or fixed) PID of eqs. (20)-(24) (docs/cosimulation.md).

A thin adapter over :class:`~nfal.models.control_law.DiscreteControlLaw`:

* gains: ``design = gain-scheduled`` -> :func:`design_schedule` over [reference_min, reference_max]
  (the work range 50-200 um by default; a film that cannot hold 200 um needs a smaller one), cut by
  :func:`realizable_schedule` when ``realizable_only``; ``design = fixed`` -> :func:`fixed_design`
  at ``design_height``. Both from the rig parameters, the calibration (K and, from an identified
  rig's file, the damping correction of eq. (6)) and Table 2's cut-offs; ``placement`` chooses the
  loop whose poles are placed: ``sampled`` (the default: the loop the law realises at ``sample_rate``,
  :mod:`~nfal.models.sampled_design`; it realises every design, so no gains are held) or
  ``continuous`` (eqs. 23-24, the paper; held below 90 um when ``realizable_only``).
* sampling: at every communication point that is a whole number of sample periods from the start
  (:class:`~nfal.fmus.base.SampleClock`) the outputs are the law's output for (state, reference,
  measured_height) *at that instant*, computed when read (direct feedthrough, the pure ``law.step``);
  ``doStep`` from a sample instant commits the law's next state. Between sample instants the
  outputs hold. A communication step longer than the sample period is an error.
* bumpless start: at the end of initialisation the law starts at the equilibrium of the
  ``reference`` input, ``law.initial_state(ref, SimplifiedPlant(rig, K).equilibrium_excitation(ref))``
  as :mod:`nfal.models.closed_loop` does.
* ``drive_voltage`` = ``excitation_command`` / ``metres_per_volt`` (the voltage -> |a| map at
  resonance, an assumption of docs/cosimulation.md).
* saturation: ``saturated_time`` is how long the held command has been at ``max_excitation`` (through
  dips shorter than ``SATURATION_GAP_S``); once per such episode longer than ``saturation_warning_time`` a
  warning goes to the FMU log (the reference is beyond what the film holds with this drive limit). ``nfal run``
  lists the episodes in summary.json (``metrics.saturation``).
"""

from __future__ import annotations

import numpy as np
from pythonfmu.enums import Fmi2Status

from nfal.errors import InvalidParameterError, optional_positive, require_positive, span_um
from nfal.fmus.base import DefaultExperiment, SampleClock
from nfal.fmus.rig_contract import RigSlave
from nfal.models.control_law import (LIFT_OFF_TIME_S, SATURATION_WARNING_S, ControllerState, DiscreteControlLaw,
                                     SaturationWatch)
from nfal.models.pid_design import DesignSpec, design_schedule, fixed_design
from nfal.models.plant import SimplifiedPlant
from nfal.models.plausibility import MAX_METRES_PER_VOLT, require_clearance, require_plausible
from nfal.models.stability import realizable_schedule
from nfal.models.table2 import (CLOSED_LOOP_CUTOFF_HZ, FILTER_CUTOFF_HZ, FIXED_DESIGN_HEIGHT_M, MAX_EXCITATION_M,
                                REFERENCE_ZERO_RATIO, SAMPLING_RATE_HZ, STAIRCASE_LEVELS_M, WORK_RANGE_M)
from nfal.models.transducer import METRES_PER_VOLT, Transducer

DESIGNS = ("gain-scheduled", "fixed")
PLACEMENTS = ("continuous", "sampled")
#: Design heights of the gain schedule, evenly over [reference_min, reference_max].
DESIGN_HEIGHTS = 31



class Controller(RigSlave):
    """Sampled PID of eqs. (21)-(22) with saturation and anti-windup; outputs feed through from both inputs."""

    description = "Gain-scheduled (or fixed) discrete PID of the levitation height, eqs. (20)-(24)"
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=0.1, step_size=5e-4)

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.add_input("reference", STAIRCASE_LEVELS_M[0], unit="m", description="reference clearance r")
        self.add_input("measured_height", STAIRCASE_LEVELS_M[0], unit="m", description="measured clearance h")
        self.add_output("drive_voltage", unit="V", description="excitation_command / metres_per_volt",
                        depends_on=("reference", "measured_height"), getter=self._voltage)
        self.add_output("excitation_command", unit="m", description="demanded excitation amplitude |a| = u",
                        depends_on=("reference", "measured_height"), getter=self._command)
        self.add_parameter("design", "gain-scheduled", description="'gain-scheduled' (eqs. 23-24 over the work "
                           "range) or 'fixed' (the design at design_height everywhere)")
        self.add_parameter("design_height", FIXED_DESIGN_HEIGHT_M, unit="m",
                           description="design height of the fixed controller")
        self.add_parameter("placement", "sampled", description="poles placed for the 'sampled' loop the law "
                           "realises at sample_rate (default) or the 'continuous' one of eqs. (23)-(24) (the paper)")
        self.add_parameter("realizable_only", True, description="hold the gains below the lowest height the "
                           "sampled loop realises (Fig. 8; the sampled placement realises all)")
        self.add_parameter("sample_rate", SAMPLING_RATE_HZ, unit="Hz", description="sampling rate (Table 2)")
        self.add_parameter("closed_loop_cutoff", CLOSED_LOOP_CUTOFF_HZ, unit="Hz",
                           description="closed-loop -3 dB bandwidth, eq. (23) (Table 2)")
        self.add_parameter("filter_cutoff", FILTER_CUTOFF_HZ, unit="Hz",
                           description="derivative filter cut-off, eq. (22) (Table 2)")
        self.add_parameter("max_excitation", MAX_EXCITATION_M, unit="m", description="actuator saturation |a|max")
        self.add_parameter("metres_per_volt", METRES_PER_VOLT, unit="m/V",
                           description="|a| per volt at resonance (assumption)")
        self.add_parameter("reference_filter_time", 0.0, unit="s", description="time constant of the critically "
                           "damped pair the reference passes through (smoother steps); 0: the reference as given")
        self.add_parameter("feedforward", False, description="add the drive the design model (eq. 13 with the "
                           "calibration) needs to follow the reference pair's path; needs reference_filter_time > 0 "
                           "(the reference zero is then off)")
        self.add_parameter("lift_off_time", LIFT_OFF_TIME_S, unit="s", description="time constant of the lift-off "
                           "reference pair when the first sample finds the object below reference_min; "
                           "0: no lift-off mode")
        self.add_parameter("actuator_lag", Transducer().time_constant_s(), unit="s", description="the transducer's "
                           "amplitude lag 2 Q / omega_r that a lead in the law cancels; 0: no lead (the paper's law)")
        self.add_parameter("reference_zero", REFERENCE_ZERO_RATIO, description="the reference enters through a "
                           "filter that cancels the PI zero and puts its own at this many slow-pole time constants "
                           "(1: monotone steps); 0: off")
        self.add_parameter("reference_min", WORK_RANGE_M[0], unit="m", description="smallest accepted reference")
        self.add_parameter("reference_max", WORK_RANGE_M[1], unit="m", description="largest accepted reference")
        self.add_parameter("saturation_warning_time", SATURATION_WARNING_S, unit="s", description="warn (FMU log) "
                           "when the drive stays saturated at max_excitation this long: the reference is out of the "
                           "film's reach")
        self.add_output("saturated_time", unit="s", description="how long the drive has been saturated at "
                        "max_excitation, through dips under 20 ms (0 when not saturated)", getter=self._saturated_time)
        self.add_rig_parameters()
        self.law: DiscreteControlLaw | None = None
        self._clock: SampleClock | None = None
        self._state: ControllerState | None = None
        self._held = 0.0  # the command of the last sample instant
        self._cache: tuple | None = None  # (state, reference, measured, command, next state)
        self._gains: tuple | None = None  # (settings, gains) of the last design
        self._saturation = SaturationWatch(MAX_EXCITATION_M)  # the drive's episodes at max_excitation

    # --- initialisation ---------------------------------------------------------------------------
    def setup(self) -> None:
        if self.design not in DESIGNS:
            raise InvalidParameterError("design", self.design, f"one of {DESIGNS}")
        if self.placement not in PLACEMENTS:
            raise InvalidParameterError("placement", self.placement, f"one of {PLACEMENTS}")
        rig = self.build_rig()
        model = self.build_rig_calibration(rig)
        calibration = model.calibration
        sample_rate = require_positive("sample_rate", self.sample_rate)
        reference_zero = optional_positive("reference_zero", self.reference_zero)
        spec = DesignSpec(require_positive("closed_loop_cutoff", self.closed_loop_cutoff),
                          require_positive("filter_cutoff", self.filter_cutoff),
                          sample_rate if self.placement == "sampled" else None, reference_zero)
        design_height = require_clearance("design_height", self.design_height) if self.design == "fixed" else None
        low, high = (require_clearance(name, getattr(self, name)) for name in ("reference_min", "reference_max"))
        if low >= high:
            raise InvalidParameterError("reference_max", high, f"> reference_min = {low:g} m")
        require_positive("saturation_warning_time", self.saturation_warning_time)
        key = (self.design, design_height, bool(self.realizable_only), sample_rate, rig, str(self.calibration), spec,
               low, high)
        if self._gains is None or self._gains[0] != key:  # initialisation re-runs setup after every set
            self._gains = (key, self._design(design_height, sample_rate, rig, model, spec, (low, high)))
        gains = self._gains[1]
        require_plausible("metres_per_volt", require_positive("metres_per_volt", self.metres_per_volt),
                          MAX_METRES_PER_VOLT, "m/V")
        lift_off, smoothing = (optional_positive(name, getattr(self, name))
                               for name in ("lift_off_time", "reference_filter_time"))
        self.law = DiscreteControlLaw(gains, sample_rate_hz=sample_rate,
                                      max_excitation_m=require_positive("max_excitation", self.max_excitation),
                                      reference_range_m=(low, high), reference_filter_s=smoothing,
                                      lift_off_time_s=lift_off, actuator_lag_s=self.actuator_lag,
                                      reference_zero_ratio=reference_zero,
                                      feedforward=SimplifiedPlant(rig, calibration, excess_damping=model.damping)
                                      if self.feedforward else None)
        reference = self._checked_reference()
        equilibrium = float(SimplifiedPlant(rig, calibration).equilibrium_excitation(reference))
        self._state = self.law.initial_state(reference, equilibrium)
        self._held = equilibrium
        self._clock = SampleClock(self.law.period_s, self.start_time)
        self._cache = None
        self._saturation = SaturationWatch(self.law.max_excitation_m)

    def _design(self, design_height, sample_rate, rig, model, spec, reference_range):
        if self.design == "fixed":
            return fixed_design(design_height, rig, model.calibration, spec, damping=model.damping)
        gains = design_schedule(np.linspace(*reference_range, DESIGN_HEIGHTS), rig, model.calibration, spec,
                                damping=model.damping)
        if not self.realizable_only:
            return gains
        # each placement judged by its own map: Fig. 8's forward Euler, or the realised (ZOH) loop
        discretisation = "forward_euler" if spec.sample_rate_hz is None else "zoh"
        return realizable_schedule(gains, rig, sample_rate_hz=sample_rate, discretisation=discretisation)

    def _checked_reference(self) -> float:
        low, high = self.law.reference_range_m
        if not (low <= self.reference <= high):
            raise InvalidParameterError("reference", self.reference,
                                        f"within reference_min–reference_max, {span_um(low, high)} ({low:g}–{high:g} "
                                        "m: a clearance in metres)", as_shown=f"{self.reference:g} m")
        return float(self.reference)

    @property
    def law_state(self) -> ControllerState | None:
        """The law's state at the current communication point (None before initialisation ends): with :attr:`law`,
        what a loop that runs this Controller's law elsewhere starts from (the compiled loop, docs/hil.md)."""
        return self._state

    # --- outputs (feedthrough at sample instants) -----------------------------------------------------
    def _sample(self) -> tuple[float, ControllerState]:
        """law.step(state, reference, measured_height), once per (state, inputs)."""
        cache = self._cache
        if cache is not None and cache[0] is self._state and cache[1] == self.reference \
                and cache[2] == self.measured_height:
            return cache[3], cache[4]
        self._checked_reference()
        command, state = self.law.step(self._state, self.reference, self.measured_height)
        self._cache = (self._state, self.reference, self.measured_height, command, state)
        return command, state

    def _command(self) -> float:
        if self.law is None:  # before initialisation ends: the start value
            return 0.0
        if self._clock.is_sample(self.time):
            return self._sample()[0]
        return self._held

    def _voltage(self) -> float:
        return self._command() / self.metres_per_volt

    def step(self, current_time: float, step_size: float) -> None:
        self._clock.check_step(step_size)
        if self._clock.is_sample(current_time):
            self._held, self._state = self._sample()  # checks the reference (or did, for these inputs)
            self._watch_saturation(current_time)
        else:
            self._checked_reference()

    def _watch_saturation(self, now: float) -> None:
        """Track how long the drive has been at max_excitation (:class:`SaturationWatch`); log a warning once per
        saturation longer than saturation_warning_time."""
        watch = self._saturation
        watch.update(now, self._held)
        if watch.warning_due(now, self.saturation_warning_time):
            self.log(f"drive saturated at |a| = {self.max_excitation * 1e6:.3g} um for "
                     f"{now - watch.since_s:.3g} s (since t = {watch.since_s:.4g} s): the reference "
                     f"{self.reference * 1e6:.4g} um is out of reach (measured {self.measured_height * 1e6:.4g} um); "
                     "the film cannot hold it with this drive limit", Fmi2Status.warning)

    def _saturated_time(self) -> float:
        return self._saturation.duration_s(self.time)

    # --- FMU state ----------------------------------------------------------------------------------
    def get_internal_state(self) -> dict:
        state = self._state
        watch = self._saturation
        return {"held": self._held, "saturated_since": watch.since_s, "warned": watch.warned,
                "last_at_limit": watch.last_at_limit_s,
                "law": None if state is None else state.as_list()}

    def set_internal_state(self, state: dict) -> None:
        self._held = float(state["held"])
        self._saturation = SaturationWatch(self._saturation.limit_m, state.get("saturated_since"),
                                           float(state.get("last_at_limit", 0.0)), bool(state.get("warned", False)))
        law = state["law"]
        self._state = None if law is None else ControllerState.from_list(law)
        self._cache = None
        if self.law is not None:
            self._clock = SampleClock(self.law.period_s, self.start_time)
