"""ReynoldsPlant FMU: the full model, Reynolds' equation (3)-(5) coupled to the object (4), (15).

``film_solver`` chooses how the film is solved (docs/film_solvers.md):

* ``harmonic_balance`` (default): the film's periodic steady state K(sigma, delta) by harmonic balance
  (``harmonics`` in the fast time, ``radial_nodes`` radial nodes, Richardson-extrapolated to twice the
  nodes), tabulated once at set-up (and kept on disk: :func:`~nfal.models.film_force_table.cached_table`)
  (:class:`~nfal.models.film_force_table.FilmForceTable`), drives the object's slow motion with the damping of
  eq. (6) (:class:`~nfal.models.averaged_plant.AveragedFilmPlant`, stepped like the SlowPlant: RK4, the exact
  event-handling integrator near the surface or, with ``near_surface`` = 'fast', the real-time one). Faster
  than real time.
* ``time_marching``: the reference, a thin adapter over the stepping API of
  :class:`~nfal.models.coupled.CoupledModel` (below). Per
communication step every excitation period that starts in the step is marched in full with the held
|a| = ``excitation_amplitude`` (BDF2 film + object, ``radial_nodes`` x ``steps_per_period``); the
outputs are those of the last period marched (mean clearance, mean velocity, fast oscillation
amplitude), so they depend on the state alone. The excitation form is ``shape``.

``drive_frequency``: when it differs from the frequency the model was built for by more than a relative
``FREQUENCY_TOLERANCE`` (fmus/base.py), the model is rebuilt for it and the state carried over
(:meth:`CoupledModel.adopt`).

Contact (the full model has none; docs/cosimulation.md): when the film gap closes during a step (the
vibrating surface reaches the object) the object lands: it rests at ``rest_gap`` with zero velocity.
It lifts off at the start of the first step whose held |a| gives a time-averaged film force (eq. 12,
with the ``calibration`` K) above its weight at ``rest_gap``; the full model then restarts from a
quasi-steady film with the object at rest at the lowest clearance where the surface clears it,
max(rest_gap, 1.05 |a| max eps_hat).
"""

from __future__ import annotations

import numpy as np

from nfal.errors import GapClosedError, InvalidParameterError
from nfal.fmus.base import DefaultExperiment, NfalSlave
from nfal.models.averaged_plant import AveragedFilmPlant
from nfal.models.coupled import CoupledModel, CoupledState
from nfal.models.excitation import largest_excursion, parse_shape
from nfal.models.film_force_table import FilmForceTable, cached_table
from nfal.models.fixed_step_plant import NEAR_SURFACE, FixedStepPlant
from nfal.models.plant import PlantState, SimplifiedPlant
from nfal.models.reynolds import check_grid

#: Lift-off clearance margin over the surface's largest excursion |a| max eps_hat.
LIFT_OFF_MARGIN = 1.05
FILM_SOLVERS = ("harmonic_balance", "time_marching")


class ReynoldsPlant(NfalSlave):
    """Eqs. (3)-(5) and (15): squeeze film by finite volumes and BDF2, coupled to the object's motion."""

    description = "Full squeeze-film model (Reynolds eq. 3-5 coupled to the object, eq. 4/15); inputs held over a step"
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=0.01, step_size=5e-4)

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.add_plant_interface()
        self.add_output("oscillation_amplitude", unit="m",
                        description="amplitude of the object's fast oscillation chi (eq. 1)")
        self.add_parameter("film_solver", "harmonic_balance", description="'harmonic_balance' (periodic film force, "
                           "tabulated once; faster than real time) or 'time_marching' (the reference: every period "
                           "marched)")
        self.add_parameter("radial_nodes", 41, description="radial finite-volume nodes of the film (>= 5)")
        self.add_parameter("harmonics", 6, description="harmonic balance: harmonics kept in the fast time (>= 1)")
        self.add_parameter("near_surface", "exact", description="harmonic balance: integrator below 3 rest gaps, "
                           "'exact' (event handling) or 'fast' (real-time capable)")
        self.add_parameter("steps_per_period", 64, description="time marching: BDF2 steps per excitation period (>= 8)")
        self.add_parameter("envelope_following", True, description="envelope following within a step (pays only "
                           "for steps of many excitation periods)")
        self.add_parameter("shape", "paper", description="excitation form: 'paper' (Fig. 3 stand-in), 'piston', "
                           "'plate:N' or the path of a CSV of (R, eps)")
        self._shape = None
        self._model: CoupledModel | None = None
        self._state: CoupledState | None = None
        self._lift_off: SimplifiedPlant | None = None
        self._table: FilmForceTable | None = None
        self._averaged: FixedStepPlant | None = None

    # --- initialisation ---------------------------------------------------------------------------
    def setup(self) -> None:
        rest_gap, height, velocity = self.checked_release()
        check_grid(self.radial_nodes, self.steps_per_period, names=("radial_nodes", "steps_per_period"))
        if self.harmonics < 1:
            raise InvalidParameterError("harmonics", self.harmonics, "a whole number >= 1")
        for name, choices in (("film_solver", FILM_SOLVERS), ("near_surface", NEAR_SURFACE)):
            if str(getattr(self, name)) not in choices:
                raise InvalidParameterError(name, getattr(self, name), f"one of {', '.join(choices)}")
        self._shape = parse_shape(str(self.shape))
        self._largest_excursion = largest_excursion(self._shape(np.linspace(0.0, 1.0, 401)))
        if str(self.film_solver) == "harmonic_balance":
            self._setup_averaged(height, velocity)
            return
        self._lift_off = SimplifiedPlant(self.build_rig(), self.build_calibration(), rest_gap=rest_gap)
        self._model = self._build_model(self.checked_frequency())
        excitation = self.checked_excitation()
        self._state = self._model.initial_state(height, velocity, excitation, self.start_time)
        self._publish(self._state)
        self.resting = False

    def _setup_averaged(self, height: float, velocity: float) -> None:
        """Tabulate the periodic film force once and release the object on it."""
        self._table = cached_table(self._shape, nodes=int(self.radial_nodes), harmonics=int(self.harmonics),
                                   rig=self.build_rig())
        self._averaged = self._build_averaged(self.checked_frequency())
        self.height, self.velocity, self.oscillation_amplitude = height, velocity, 0.0
        self.resting = self._averaged.plant.rests(PlantState(height, velocity), self.checked_excitation())

    def _build_averaged(self, frequency: float) -> FixedStepPlant:
        plant = AveragedFilmPlant(self.build_rig(frequency), self._table, rest_gap=self.rest_gap)
        return FixedStepPlant(plant, near_surface=str(self.near_surface))

    def _step_averaged(self, step_size: float) -> None:
        excitation, frequency = self.checked_excitation(), self.checked_frequency()
        if self.frequency_changed(frequency, self._averaged.plant.rig.frequency):
            self._averaged = self._build_averaged(frequency)
        # as the marched film: the gap closes
        if not self.resting and excitation * self._largest_excursion >= self.height:
            self.log(f"touchdown: the surface's excursion {excitation * self._largest_excursion * 1e6:.4g} um reaches "
                     f"the object at {self.height * 1e6:.4g} um")
            self.height, self.velocity, self.resting, self.oscillation_amplitude = self.rest_gap, 0.0, True, 0.0
            return  # rests for the step, as the marched film does
        state = self._averaged.advance(PlantState(self.height, self.velocity, self.resting), excitation, step_size)
        self.height, self.velocity, self.resting = float(state.height), float(state.velocity), bool(state.resting)
        self.oscillation_amplitude = 0.0 if self.resting else self._averaged.plant.oscillation(self.height, excitation)

    def _build_model(self, frequency: float) -> CoupledModel:
        return CoupledModel(self.build_rig(frequency), self._shape, nodes=int(self.radial_nodes),
                            steps_per_period=int(self.steps_per_period), envelope=bool(self.envelope_following))

    def _publish(self, state: CoupledState) -> None:
        self.height, self.velocity, self.oscillation_amplitude = state.height, state.velocity, state.oscillation

    # --- stepping -----------------------------------------------------------------------------------
    def step(self, current_time: float, step_size: float) -> None:
        if self._averaged is not None:
            self._step_averaged(step_size)
            return
        excitation = self.checked_excitation()
        frequency = self.checked_frequency()
        if self.frequency_changed(frequency, self._model.rig.frequency):
            previous, self._model = self._model, self._build_model(frequency)
            self._state = self._model.adopt(self._state, previous)
        state = self._state
        if self.resting:
            plant = self._lift_off
            if plant.levitation_force(plant.rest_gap, excitation) <= plant.weight:
                self._state = CoupledState(state.vector, current_time + step_size, state.epoch_s, state.period_index,
                                           self.rest_gap, 0.0, 0.0)
                self._publish(self._state)
                return
            start = max(self.rest_gap, LIFT_OFF_MARGIN * excitation * self._largest_excursion)
            state = self._model.initial_state(start, 0.0, excitation, current_time)
            self.resting = False
        try:
            self._state = self._model.advance(state, excitation, step_size)
        except GapClosedError as exc:
            self.log(f"touchdown in the step from t = {current_time:.9g} s: {exc}")
            self.resting = True
            self._state = CoupledState(state.vector, current_time + step_size, state.epoch_s, state.period_index,
                                       self.rest_gap, 0.0, 0.0)
        self._publish(self._state)

    # --- FMU state ----------------------------------------------------------------------------------
    def get_internal_state(self) -> dict:
        if self._averaged is not None:  # height, velocity, resting are outputs (saved by the base)
            return {"frequency": self._averaged.plant.rig.frequency}
        state = self._state
        if state is None:
            return {}
        return {"frequency": self._model.rig.frequency, "vector": state.vector.tolist(), "time_s": state.time_s,
                "epoch_s": state.epoch_s, "period_index": state.period_index, "height": state.height,
                "velocity": state.velocity, "oscillation": state.oscillation}

    def set_internal_state(self, state: dict) -> None:
        if not state or self._shape is None:
            return
        if self._averaged is not None:
            if state["frequency"] != self._averaged.plant.rig.frequency:
                self._averaged = self._build_averaged(float(state["frequency"]))
            return
        if state["frequency"] != self._model.rig.frequency:
            self._model = self._build_model(float(state["frequency"]))
        self._state = CoupledState(np.array(state["vector"], dtype=float), float(state["time_s"]),
                                   float(state["epoch_s"]), int(state["period_index"]), float(state["height"]),
                                   float(state["velocity"]), float(state["oscillation"]))
