"""SlowPlant FMU: the simplified slow model of eq. (13) with touchdown and lift-off (docs/cosimulation.md).

Per communication step the excitation amplitude ``excitation_amplitude`` = |a| and the drive frequency
are held (zero-order hold) and the state (clearance, velocity, resting) is advanced by
:class:`~nfal.models.fixed_step_plant.FixedStepPlant` (RK4 in free flight, the event-handling
:meth:`SimplifiedPlant.advance` near the surface). The squeeze number scales with the drive
frequency (eq. 2): the stepping plant is rebuilt for the held ``drive_frequency`` when it differs
from the one it was built for by more than a relative ``FREQUENCY_TOLERANCE`` (fmus/base.py).

Outputs come from the state alone (no feedthrough). Lift-off from rest: when the held |a| already
pushes harder than gravity at the rest gap at the start of a step, the object leaves the surface at
that instant (:meth:`SimplifiedPlant.advance` decides rest and lift-off at the start of each step).
"""

from __future__ import annotations

import math

from nfal.fmus.base import DefaultExperiment, NfalSlave
from nfal.models.fixed_step_plant import FixedStepPlant
from nfal.models.plant import PlantState, SimplifiedPlant


class SlowPlant(NfalSlave):
    """Eq. (13): m h'' = pi r0^2 p_a (|a|/h)^2 K(sigma(h)) - 3 pi mu r0^4 / (2 h^3) h' - m g, in SI."""

    description = "Slow (time-averaged) levitation model, eq. (13), with touchdown and lift-off; inputs held over a step"
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=0.1, step_size=5e-4)

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.add_plant_interface()
        self._calibration = None
        self._plant: FixedStepPlant | None = None
        self._plant_frequency = math.nan

    # --- the model --------------------------------------------------------------------------------
    def setup(self) -> None:
        _, height, velocity = self.checked_release()
        self.build_rig()  # checks the rig parameters under their FMU names
        self._calibration = self.build_calibration()
        self._rebuild(self.checked_frequency())
        self.height, self.velocity = height, velocity
        self.resting = self._plant.plant.rests(PlantState(self.height, self.velocity), self.checked_excitation())

    def _rebuild(self, frequency: float) -> None:
        plant = SimplifiedPlant(self.build_rig(frequency), self._calibration, rest_gap=self.rest_gap)
        self._plant, self._plant_frequency = FixedStepPlant(plant), frequency

    def step(self, current_time: float, step_size: float) -> None:
        excitation = self.checked_excitation()
        frequency = self.checked_frequency()
        if self.frequency_changed(frequency, self._plant_frequency):
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
