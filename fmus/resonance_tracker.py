"""ResonanceTracker FMU: the transducer's resonance and the PLL that tracks it (Fig. 7), over nfal.models.

A thin adapter over :class:`nfal.models.pll.ResonanceTracker` (models/transducer.py: the driven resonator
in slow time, eqs. T1-T4; models/pll.py: the PLL, eqs. P1-P2). Variables per docs/cosimulation.md.

* The PLL samples at ``pll_rate`` on the communication points a whole number of periods from the start;
  at a sample instant the outputs are computed when read (the PLL's law on the envelope as it is then, and
  the amplitude from then on); ``doStep`` commits the sample and integrates the envelope exactly over the
  step with the inputs and the new drive frequency held. Between instants the PLL's outputs hold.
* Every output declares a dependency on both inputs: in the quasi-static mode (``transducer_dynamics``
  false) ‖a‖ is the steady-state response at the current voltage and shift; with dynamics it is the state.
* It starts in steady state at ``resonance_frequency`` for the inputs set before initialisation ends.
* The PLL's gains come from ``pll_bandwidth`` (eq. P2 of models/pll.py), for the mode chosen.
"""

from __future__ import annotations

import dataclasses
import sys

import numpy as np

from nfal.errors import InvalidParameterError, require_finite
from nfal.fmus.base import CORE_TIME, SAMPLE_TOLERANCE, DefaultExperiment, NfalSlave, SampleClock
from nfal.models import pll as pll_model
from nfal.models import tracker_core
from nfal.models.transducer import METRES_PER_VOLT, QUALITY_FACTOR, RESONANCE_FREQUENCY_HZ, Transducer

INPUTS = ("drive_voltage", "resonance_shift")
#: Largest drive voltage amplitude [V]: piezo drivers stop well below 1 kV (the rig emulator's default limit: 150 V).
MAX_DRIVE_VOLTAGE_V = 1000.0


class ResonanceTracker(NfalSlave):
    """Transducer (Butterworth-Van Dyke resonator in slow time) + digital PLL; outputs ‖a‖ and the drive frequency."""

    description = ("Transducer resonance (driven 2nd-order resonator as a complex envelope) and the PLL that "
                   "tracks it: drive voltage and resonance shift in, excitation amplitude and drive frequency out")
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=1.0, step_size=5e-4)

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.add_input("drive_voltage", 0.0, unit="V", description="drive voltage amplitude V (>= 0)")
        self.add_input("resonance_shift", 0.0, unit="Hz",
                       description="shift of the transducer's resonance from resonance_frequency (e.g. thermal drift)")
        self.add_output("excitation_amplitude", unit="m", description="excitation magnitude ||a|| = |A|",
                        depends_on=INPUTS, getter=lambda: self._outputs().excitation_amplitude_m)
        self.add_output("drive_frequency", unit="Hz",
                        description="drive frequency set by the PLL (held between samples)",
                        depends_on=INPUTS, getter=lambda: self._outputs().drive_frequency_hz)
        self.add_output("locked", kind=bool,
                        description="lock detector: |phase_error| < lock_threshold for lock_samples samples",
                        depends_on=INPUTS, getter=lambda: self._outputs().locked)
        self.add_output("phase_error", unit="rad",
                        description="phase of the displacement relative to the drive + 90 deg, wrapped",
                        depends_on=INPUTS, getter=lambda: self._outputs().phase_error_rad)
        self.add_parameter("resonance_frequency", RESONANCE_FREQUENCY_HZ, unit="Hz",
                           description="nominal resonance f_r of the transducer; the PLL's centre frequency")
        self.add_parameter("quality_factor", QUALITY_FACTOR, unit="1", description="quality factor Q of the resonance")
        self.add_parameter("metres_per_volt", METRES_PER_VOLT, unit="m/V",
                           description="||a|| per volt at resonance, steady state")
        self.add_parameter("transducer_dynamics", True,
                           description="true: envelope dynamics (time constant 2Q/omega_r); false: quasi-static")
        self.add_parameter("pll_enabled", True, description="false: fixed drive frequency resonance_frequency")
        self.add_parameter("pll_rate", pll_model.PLL_RATE_HZ, unit="Hz", description="PLL sample rate")
        self.add_parameter("pll_bandwidth", pll_model.PLL_BANDWIDTH_HZ, unit="Hz",
                           description="closed-loop bandwidth of the PLL (first order), below pll_rate / 10")
        self.add_parameter("lock_threshold", pll_model.LOCK_THRESHOLD_RAD, unit="rad",
                           description="|phase error| below which samples count towards lock, in (0, pi/2)")
        self.add_parameter("lock_samples", pll_model.LOCK_SAMPLES,
                           description="samples in a row below lock_threshold to declare lock (>= 1)")
        self._tracker: pll_model.ResonanceTracker | None = None
        self._clock: SampleClock | None = None
        self._state: pll_model.TrackerState | None = None
        self._last_outputs: tuple | None = None  # ((state, inputs, time), outputs)

    # --- model ------------------------------------------------------------------------------------------
    def _build(self) -> None:
        transducer = Transducer(self.resonance_frequency, self.quality_factor, self.metres_per_volt)
        if self.lock_samples < 1:
            raise InvalidParameterError("lock_samples", self.lock_samples, "a whole number >= 1")
        pll = pll_model.PhaseLockedLoop.designed(
            transducer, bandwidth_hz=self.pll_bandwidth, sample_rate_hz=self.pll_rate,
            quasi_static=not self.transducer_dynamics, enabled=bool(self.pll_enabled),
            lock_threshold_rad=self.lock_threshold, lock_samples=int(self.lock_samples))
        tracker = pll_model.ResonanceTracker(transducer, pll, dynamics=bool(self.transducer_dynamics))
        self._tracker, self._clock = tracker, SampleClock(pll.period_s, self.start_time)

    def setup(self) -> None:
        self._tracker = self._clock = self._state = None
        self._build()
        self._check_inputs()
        self._state = self._tracker.initial_state(self.drive_voltage, self.resonance_shift)

    def _check_inputs(self) -> None:
        """``drive_voltage`` in [0, MAX_DRIVE_VOLTAGE_V] V; ``resonance_shift`` within half the resonance frequency."""
        voltage = require_finite("drive_voltage", self.drive_voltage,
                                 f"a finite voltage in [0, {MAX_DRIVE_VOLTAGE_V:g}] V")
        if not 0.0 <= voltage <= MAX_DRIVE_VOLTAGE_V:
            raise InvalidParameterError("drive_voltage", voltage,
                                        f"in [0, {MAX_DRIVE_VOLTAGE_V:g}] V (a piezo driver's range)")
        limit = 0.5 * float(self.resonance_frequency)
        if not abs(require_finite("resonance_shift", self.resonance_shift)) < limit:
            raise InvalidParameterError("resonance_shift", self.resonance_shift,
                                        f"within +-{limit:g} Hz (half the resonance frequency)")

    def _outputs_of_the_state(self) -> frozenset[str]:
        """With the transducer's dynamics the PLL measures the envelope, a state: every output is the state's."""
        if self._tracker is None or not self._tracker.dynamics:
            return frozenset()
        return frozenset({"excitation_amplitude", "drive_frequency", "locked", "phase_error"})

    def _outputs(self) -> pll_model.TrackerOutputs:
        if self._state is None:  # before initialisation ends: the start values
            return pll_model.TrackerOutputs(0.0, float(self.resonance_frequency), False, 0.0)
        key = (self._state, self.drive_voltage, self.resonance_shift, self.time)
        cached = self._last_outputs
        if cached is None or cached[0][0] is not key[0] or cached[0][1:] != key[1:]:
            # once per (state, inputs, time): a master reads the four outputs one by one
            if not self._tracker.dynamics:  # the quasi-static transducer's outputs read the inputs: checked
                self._check_inputs()
            cached = self._last_outputs = (key, self._tracker.outputs(
                self._state, self.drive_voltage, self.resonance_shift, at_sample=self._clock.is_sample(self.time)))
        return cached[1]

    def step(self, current_time: float, step_size: float) -> None:
        self._clock.check_step(step_size)
        self._check_inputs()
        self._state = self._tracker.advance(self._state, self.drive_voltage, self.resonance_shift, step_size,
                                            at_sample=self._clock.is_sample(current_time))

    # --- the compiled core: the runtime steps the tracker without Python (models/tracker_core.py) ------------
    def _core_address(self) -> int | None:
        if not self._outputs_of_the_state() or "numba" not in sys.modules:
            return None  # the quasi-static transducer's outputs are computed; numba's start would cost more
        return tracker_core.step_address()  # compiled, or loaded from numba's cache, on first use

    def _packed_core(self) -> np.ndarray:
        slots = (*(self._cache_slot(name) for name in ("drive_voltage", "resonance_shift", "excitation_amplitude",
                                                        "drive_frequency", "locked", "phase_error")), CORE_TIME)
        return tracker_core.pack(slots, self._tracker, MAX_DRIVE_VOLTAGE_V, SAMPLE_TOLERANCE, self._clock.start_time_s,
                                 self._state)

    def _take_core_state(self) -> None:
        x = self._core_data[tracker_core.STATE:tracker_core.STATE + tracker_core.STATE_SIZE].tolist()
        self._state = pll_model.TrackerState(complex(x[0], x[1]),
                                             pll_model.PllState(x[2], x[3], x[4], int(x[5]), bool(x[6])))

    # --- FMU state ----------------------------------------------------------------------------------------
    def get_internal_state(self) -> dict:
        if self._state is None:
            return {}
        envelope = self._state.envelope_m
        return {"envelope_m": [envelope.real, envelope.imag], "pll": dataclasses.asdict(self._state.pll)}

    def set_internal_state(self, state: dict) -> None:
        if not state:
            self._state = None
            return
        if self._tracker is None:
            self._build()
        try:
            real, imag = (float(v) for v in state["envelope_m"])
            self._state = pll_model.TrackerState(complex(real, imag), pll_model.PllState(**state["pll"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise InvalidParameterError("FMU state", type(state).__name__,
                                        f"a ResonanceTracker state ({exc})") from None
