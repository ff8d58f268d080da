"""The Reynolds plant's two film solvers, one class each behind one interface (docs/film_solvers.md).

The ReynoldsPlant FMU picks a class by its ``film_solver`` parameter, as scipy's ``solve_ivp`` picks a solver class
by its method name, and steps the object through :class:`FilmBackend`'s four calls; no code branches on the
solver. Both share one contact model (:class:`Contact`):

* :class:`HarmonicBalanceFilm` (``harmonic_balance``): the film's periodic steady state K(sigma, delta),
  tabulated once (:class:`~nfal.models.film_force_table.FilmForceTable`), drives the object's slow motion
  (:class:`~nfal.models.averaged_plant.AveragedFilmPlant` stepped by
  :class:`~nfal.models.fixed_step_plant.FixedStepPlant`).
* :class:`TimeMarchingFilm` (``time_marching``): the reference, every excitation period that starts in a step
  marched in full (:class:`~nfal.models.coupled.CoupledModel`); the outputs are those of the last period marched.

A drive frequency that moves (relative, more than ``FREQUENCY_TOLERANCE``) rebuilds the model for it, the state
carried over (:func:`~nfal.models.rig.frequency_changed`).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Callable, Protocol

import numpy as np

from nfal.errors import GapClosedError
from nfal.models.averaged_plant import AveragedFilmPlant
from nfal.models.coupled import CoupledModel, CoupledState
from nfal.models.film_force_table import FilmForceTable
from nfal.models.fixed_step_plant import FixedStepPlant
from nfal.models.plant import PlantState, SimplifiedPlant
from nfal.models.rig import RigParameters, frequency_changed

#: Lift-off clearance margin over the surface's largest excursion |a| max eps_hat.
LIFT_OFF_CLEARANCE_FACTOR = 1.05

#: A rig at a drive frequency [Hz] (the FMU's parameters at that frequency).
RigAt = Callable[[float], RigParameters]


@dataclasses.dataclass(frozen=True)
class Body:
    """What the plant outputs: clearance [m], velocity [m/s], resting, amplitude of the fast oscillation [m]."""

    height: float
    velocity: float
    resting: bool
    oscillation: float = 0.0


@dataclasses.dataclass(frozen=True)
class Contact:
    """Landing and lift-off (the full model has none; docs/cosimulation.md). When the film gap closes (the vibrating
    surface reaches the object) the object lands and rests at ``rest_gap`` with zero velocity; it lifts off when the
    time-averaged film force of ``lift`` (eq. 12) at ``rest_gap`` exceeds its weight, from the lowest clearance where
    the surface clears it, max(rest_gap, LIFT_OFF_CLEARANCE_FACTOR |a| max eps_hat)."""

    rest_gap: float
    largest_excursion: float  #: max eps_hat of the excitation form
    log: Callable[[str], None]  #: where a landing is told
    lift_model: Callable[[], SimplifiedPlant]  #: builds the plant whose film force decides the lift-off (on first use)

    @functools.cached_property
    def lift(self) -> SimplifiedPlant:
        return self.lift_model()

    def touches(self, height: float, excitation: float) -> bool:
        """The surface's excursion reaches an object at ``height``."""
        return excitation * self.largest_excursion >= height

    def stays(self, excitation: float) -> bool:
        """A resting object stays on the surface under ``excitation``."""
        return self.lift.levitation_force(self.rest_gap, excitation) <= self.lift.weight

    def lift_off_height(self, excitation: float) -> float:
        return max(self.rest_gap, LIFT_OFF_CLEARANCE_FACTOR * excitation * self.largest_excursion)

    def landed(self, message: str) -> Body:
        """Tell ``message``; the body at rest on the surface."""
        self.log(message)
        return Body(self.rest_gap, 0.0, True)


class FilmBackend(Protocol):
    """A film solver of the ReynoldsPlant: release the object, step it, save and restore what is not in a Body."""

    def release(self, height: float, velocity: float, excitation: float, time_s: float) -> Body: ...

    def advance(self, body: Body, excitation: float, frequency: float, time_s: float, step_s: float) -> Body: ...

    def internal_state(self) -> dict: ...

    def restore(self, state: dict) -> None: ...


class HarmonicBalanceFilm:
    """The periodic film force, tabulated once, driving the object's slow motion (faster than real time)."""

    def __init__(self, rig_at: RigAt, frequency: float, table: FilmForceTable, contact: Contact, *,
                 near_surface: str) -> None:
        self.rig_at, self.table, self.contact, self.near_surface = rig_at, table, contact, near_surface
        self._stepper = self._build(frequency)

    def _build(self, frequency: float) -> FixedStepPlant:
        plant = AveragedFilmPlant(self.rig_at(frequency), self.table, rest_gap=self.contact.rest_gap)
        return FixedStepPlant(plant, near_surface=self.near_surface)

    @property
    def stepper(self) -> FixedStepPlant:
        """The free flight's integrator, for the drive frequency of the last step."""
        return self._stepper

    def release(self, height: float, velocity: float, excitation: float, time_s: float) -> Body:
        return Body(height, velocity, self._stepper.plant.rests(PlantState(height, velocity), excitation))

    def advance(self, body: Body, excitation: float, frequency: float, time_s: float, step_s: float) -> Body:
        if frequency_changed(frequency, self._stepper.plant.rig.frequency):
            self._stepper = self._build(frequency)
        if not body.resting and self.contact.touches(body.height, excitation):  # as the marched film: the gap closes
            reach = excitation * self.contact.largest_excursion
            return self.contact.landed(f"touchdown: the surface's excursion {reach * 1e6:.4g} um reaches the object at "
                                       f"{body.height * 1e6:.4g} um")
        state = self._stepper.advance(PlantState(body.height, body.velocity, body.resting), excitation, step_s)
        height, resting = float(state.height), bool(state.resting)
        return Body(height, float(state.velocity), resting,
                    0.0 if resting else self._stepper.plant.oscillation(height, excitation))

    def internal_state(self) -> dict:  # the body is the FMU's outputs
        return {"frequency": self._stepper.plant.rig.frequency}

    def restore(self, state: dict) -> None:
        if state["frequency"] != self._stepper.plant.rig.frequency:
            self._stepper = self._build(float(state["frequency"]))


class TimeMarchingFilm:
    """Every excitation period marched (BDF2 film and object): the reference."""

    def __init__(self, rig_at: RigAt, frequency: float, shape, contact: Contact, *, nodes: int, steps_per_period: int,
                 envelope: bool) -> None:
        self.rig_at, self.shape, self.contact = rig_at, shape, contact
        self.options = {"nodes": nodes, "steps_per_period": steps_per_period, "envelope": envelope}
        self._model = self._build(frequency)
        self._state: CoupledState | None = None

    def _build(self, frequency: float) -> CoupledModel:
        return CoupledModel(self.rig_at(frequency), self.shape, **self.options)

    def release(self, height: float, velocity: float, excitation: float, time_s: float) -> Body:
        self._state = self._model.initial_state(height, velocity, excitation, time_s)
        return self._body(False)

    def advance(self, body: Body, excitation: float, frequency: float, time_s: float, step_s: float) -> Body:
        if frequency_changed(frequency, self._model.rig.frequency):
            previous, self._model = self._model, self._build(frequency)
            self._state = self._model.adopt(self._state, previous)
        state = self._state
        if body.resting:
            if self.contact.stays(excitation):
                self._state = self._at_rest(state, time_s + step_s)
                return self._body(True)
            state = self._model.initial_state(self.contact.lift_off_height(excitation), 0.0, excitation, time_s)
        try:
            self._state = self._model.advance(state, excitation, step_s)
        except GapClosedError as exc:
            self._state = self._at_rest(state, time_s + step_s)
            self.contact.landed(f"touchdown in the step from t = {time_s:.9g} s: {exc}")
            return self._body(True)
        return self._body(False)

    def _at_rest(self, state: CoupledState, time_s: float) -> CoupledState:
        return CoupledState(state.vector, time_s, state.epoch_s, state.period_index, self.contact.rest_gap, 0.0, 0.0)

    def _body(self, resting: bool) -> Body:
        state = self._state
        return Body(state.height, state.velocity, resting, state.oscillation)

    def internal_state(self) -> dict:
        state = self._state
        if state is None:
            return {}
        return {"frequency": self._model.rig.frequency, "vector": state.vector.tolist(), "time_s": state.time_s,
                "epoch_s": state.epoch_s, "period_index": state.period_index, "height": state.height,
                "velocity": state.velocity, "oscillation": state.oscillation}

    def restore(self, state: dict) -> None:
        if not state:
            return
        if state["frequency"] != self._model.rig.frequency:
            self._model = self._build(float(state["frequency"]))
        self._state = CoupledState(np.array(state["vector"], dtype=float), float(state["time_s"]),
                                   float(state["epoch_s"]), int(state["period_index"]), float(state["height"]),
                                   float(state["velocity"]), float(state["oscillation"]))
