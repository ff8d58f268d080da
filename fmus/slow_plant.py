"""SlowPlant FMU: the simplified slow model of eq. (13) with touchdown and lift-off (docs/cosimulation.md).

Per communication step the excitation amplitude ``excitation_amplitude`` = |a| and the drive frequency
are held (zero-order hold) and the state (clearance, velocity, resting) is advanced by
:class:`~nfal.models.fixed_step_plant.FixedStepPlant` (RK4 in free flight, the event-handling
:meth:`SimplifiedPlant.advance` near the surface). The squeeze number scales with the drive
frequency (eq. 2): the stepping plant is rebuilt for the held ``drive_frequency`` when it differs
from the one it was built for by more than a relative ``FREQUENCY_TOLERANCE`` (models/rig.py).

Outputs come from the state alone (no feedthrough). Lift-off from rest: when the held |a| already
pushes harder than gravity at the rest gap at the start of a step, the object leaves the surface at
that instant (:meth:`SimplifiedPlant.advance` decides rest and lift-off at the start of each step).

``excess_damping_height`` > 0 scales eq. (6)'s damping by 1 + (h / excess_damping_height)^excess_damping_exponent
(:class:`~nfal.models.plant.ExcessDamping`, Sec. 3.3): a "truth" plant damped like the rig at large gaps.
The rig-like choice is 137e-6 m and 6; 0 (the default) leaves eq. (6) as it is, or applies the damping
correction of the ``calibration`` file when it has one (an identified rig's; giving both is an error).

``near_surface`` = "fast" swaps the exact event-handling integrator near the surface (about 4 ms per step
at lift-off) for the fast one of :mod:`nfal.models.fixed_step_plant` (a few us, within 1 % of the
clearance): what the real-time rig emulator needs.
"""

from __future__ import annotations

import math
import sys

from nfal.errors import InvalidParameterError, require_finite, require_non_negative
from nfal.fmus.base import DefaultExperiment
from nfal.fmus.rig_contract import RigSlave
from nfal.models import slow_kernels
from nfal.models.fixed_step_plant import FixedStepPlant
from nfal.models.plant import DampingModel, ExcessDamping, PlantState, SimplifiedPlant
from nfal.models.rig import frequency_changed


class SlowPlant(RigSlave):
    """Eq. (13): m h'' = pi r0^2 p_a (|a|/h)^2 K(sigma(h)) - 3 pi mu r0^4 / (2 h^3) h' - m g, in SI."""

    description = ("Slow (time-averaged) levitation model, eq. (13), with touchdown and lift-off; inputs held over "
                   "a step")
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=0.1, step_size=5e-4)
    #: Steps in Python (models/jit.py) that cost about what compiling the kernels costs: a 10 ms run in a new Python
    #: 0.38-0.45 s of CPU so, 1.61-1.75 s compiled; a step 0.27-0.52 ms in Python (``python bench/bench_startup.py``).
    python_steps = 1500

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.add_plant_interface()
        self.add_parameter("excess_damping_height", 0.0, unit="m",
                           description="empirical excess damping (Sec. 3.3): eq. (6)'s damping times 1 + (h / this)"
                           "^excess_damping_exponent; 0 = none, rig-like 137e-6")
        self.add_parameter("excess_damping_exponent", 6.0, unit="1",
                           description="exponent (>= 1) of the excess damping; used when excess_damping_height > 0")
        self.add_parameter("near_surface", "exact", description="integrator below 3 rest gaps: 'exact' (event "
                           "handling, slow) or 'fast' (exponential Euler, real-time capable)")
        self._calibration = None
        self._excess_damping: DampingModel | None = None
        self._plant: FixedStepPlant | None = None
        self._plant_frequency = math.nan
        self._python_steps: int | None = None  # steps left with the kernels in Python; None: compiled

    # --- the model --------------------------------------------------------------------------------
    def setup(self) -> None:
        _, height, velocity = self.checked_release()
        calibration = self.build_rig_calibration(self.build_rig())  # build_rig checks the rig parameters
        self._calibration = calibration.calibration
        self._excess_damping = self.checked_excess_damping()
        if calibration.damping is not None:
            if self._excess_damping is not None:
                raise InvalidParameterError("excess_damping_height", self.excess_damping_height,
                                            f"0 when the calibration {self.calibration} has its own damping correction")
            self._excess_damping = calibration.damping
        self._rebuild(self.checked_frequency())
        self._plan_kernels()
        self.height, self.velocity = height, velocity
        self.resting = self._plant.plant.rests(PlantState(self.height, self.velocity), self.checked_excitation())

    def _plan_kernels(self) -> None:
        """Compile the kernels now, unless the host declared a stop time within :attr:`python_steps` steps of the
        loop's 0.5 ms and numba is not in the process yet (its import and start are most of what compiling costs);
        then they stay Python for that many steps, whatever their size."""
        short = self.stop_time is not None and "numba" not in sys.modules and \
            self.stop_time - self.start_time <= self.python_steps * type(self).default_experiment.step_size
        self._python_steps = self.python_steps if short else None
        if not short:
            slow_kernels.load()

    def _count_kernel_step(self) -> None:
        if self._python_steps == 0:
            slow_kernels.load()
            self._python_steps = None
        else:
            self._python_steps -= 1

    def checked_excess_damping(self) -> ExcessDamping | None:
        """The excess damping the parameters ask for (None when ``excess_damping_height`` is 0), checked."""
        height = require_non_negative("excess_damping_height", self.excess_damping_height,
                                      "a finite height >= 0 m (0: none)")
        # a NaN is a mistake even while unused; the range applies when used (at height 0 the exponent is ignored)
        exponent = require_finite("excess_damping_exponent", self.excess_damping_exponent, "a finite number >= 1")
        if height == 0.0:
            return None
        if exponent < 1.0:
            raise InvalidParameterError("excess_damping_exponent", exponent, "a finite number >= 1")
        return ExcessDamping(height, exponent)

    def _rebuild(self, frequency: float) -> None:
        plant = SimplifiedPlant(self.build_rig(frequency), self._calibration, rest_gap=self.rest_gap,
                                excess_damping=self._excess_damping)
        self._plant, self._plant_frequency = FixedStepPlant(plant, near_surface=str(self.near_surface),
                                                                compiled=False), frequency

    def step(self, current_time: float, step_size: float) -> None:
        excitation = self.checked_excitation()
        frequency = self.checked_frequency()
        if self._python_steps is not None:  # kernels still Python: counts down to compiling them
            self._count_kernel_step()
        if frequency_changed(frequency, self._plant_frequency):
            self._rebuild(frequency)
        state = self._plant.advance(PlantState(self.height, self.velocity, self.resting), excitation, step_size)
        self.height, self.velocity, self.resting = float(state.height), float(state.velocity), bool(state.resting)

    # --- FMU state ----------------------------------------------------------------------------------
    def get_internal_state(self) -> dict:
        # height, velocity and resting are output variables (saved by the base); the plant is rebuilt
        # from the parameters, so only its frequency is kept
        return {"plant_frequency": self._plant_frequency}

    def set_internal_state(self, state: dict) -> None:
        frequency = float(state.get("plant_frequency", math.nan))
        if self._calibration is not None and math.isfinite(frequency) and frequency != self._plant_frequency:
            self._rebuild(frequency)
