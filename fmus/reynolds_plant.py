"""ReynoldsPlant FMU: the full model, Reynolds' equation (3)-(5) coupled to the object (4), (15).

``film_solver`` chooses how the film is solved (docs/film_solvers.md), one class each in
:mod:`nfal.models.film_backends` (:data:`FILM_SOLVERS`):

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
``FREQUENCY_TOLERANCE`` (models/rig.py), the model is rebuilt for it and the state carried over
(:meth:`CoupledModel.adopt`).

Contact (the full model has none; docs/cosimulation.md; :class:`~nfal.models.film_backends.Contact`, the same for
both solvers): when the film gap closes during a step (the
vibrating surface reaches the object) the object lands: it rests at ``rest_gap`` with zero velocity.
It lifts off at the start of the first step whose held |a| gives a time-averaged film force (eq. 12,
with the ``calibration`` K) above its weight at ``rest_gap``; the full model then restarts from a
quasi-steady film with the object at rest at the lowest clearance where the surface clears it,
max(rest_gap, 1.05 |a| max eps_hat).
"""

from __future__ import annotations

import numpy as np

from nfal.errors import InvalidParameterError
from nfal.fmus.base import CORE_TIME, DefaultExperiment
from nfal.fmus.rig_contract import RigSlave
from nfal.models import plant_core
from nfal.models.excitation import largest_excursion, parse_shape
from nfal.models.film_backends import Body, Contact, FilmBackend, HarmonicBalanceFilm, TimeMarchingFilm
from nfal.models.film_force_table import cached_table
from nfal.models.fixed_step_plant import NEAR_SURFACE
from nfal.models.plant import SimplifiedPlant
from nfal.models.reynolds import check_grid


class ReynoldsPlant(RigSlave):
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
        self._film: FilmBackend | None = None
        self._core_stepper = None  # the stepper the compiled core's data was packed from (models/plant_core.py)

    # --- initialisation ---------------------------------------------------------------------------
    def setup(self) -> None:
        rest_gap, height, velocity = self.checked_release()
        check_grid(self.radial_nodes, self.steps_per_period, names=("radial_nodes", "steps_per_period"))
        if self.harmonics < 1:
            raise InvalidParameterError("harmonics", self.harmonics, "a whole number >= 1")
        for name, choices in (("film_solver", FILM_SOLVERS), ("near_surface", NEAR_SURFACE)):
            if str(getattr(self, name)) not in choices:
                raise InvalidParameterError(name, getattr(self, name), f"one of {', '.join(choices)}")
        shape = parse_shape(str(self.shape))
        contact = Contact(rest_gap, largest_excursion(shape(np.linspace(0.0, 1.0, 401))), self.log,
                          lambda: SimplifiedPlant(self.build_rig(), self.build_calibration(), rest_gap=rest_gap))
        self._film = FILM_SOLVERS[str(self.film_solver)](self, shape, contact)
        self._publish(self._film.release(height, velocity, self.checked_excitation(), self.start_time))

    def _harmonic_balance(self, shape, contact: Contact) -> HarmonicBalanceFilm:
        """The periodic film force, tabulated once (and kept on disk)."""
        table = cached_table(shape, nodes=int(self.radial_nodes), harmonics=int(self.harmonics), rig=self.build_rig())
        return HarmonicBalanceFilm(self.build_rig, self.checked_frequency(), table, contact,
                                   near_surface=str(self.near_surface))

    def _time_marching(self, shape, contact: Contact) -> TimeMarchingFilm:
        return TimeMarchingFilm(self.build_rig, self.checked_frequency(), shape, contact, nodes=int(self.radial_nodes),
                                steps_per_period=int(self.steps_per_period), envelope=bool(self.envelope_following))

    def _publish(self, body: Body) -> None:
        self.height, self.velocity, self.resting = body.height, body.velocity, body.resting
        self.oscillation_amplitude = body.oscillation

    # --- stepping -----------------------------------------------------------------------------------
    def step(self, current_time: float, step_size: float) -> None:
        body = Body(self.height, self.velocity, self.resting, self.oscillation_amplitude)
        self._publish(self._film.advance(body, self.checked_excitation(), self.checked_frequency(), current_time,
                                         step_size))

    # --- the compiled core: the runtime steps free flight without Python (models/plant_core.py) ----------------
    def _core_address(self) -> int | None:
        if not isinstance(self._film, HarmonicBalanceFilm):
            return None
        return plant_core.step_address()  # compiled, or loaded from numba's cache, on first use

    def _store_core_state(self) -> None:
        """The state is the outputs, in the buffer: the core's data changes only with a model rebuilt for a
        frequency."""
        if self._core_data is not None and self._film.stepper is not self._core_stepper:
            super()._store_core_state()

    def _packed_core(self) -> np.ndarray:
        self._core_stepper = self._film.stepper
        slots = (*(self._cache_slot(name) for name in ("excitation_amplitude", "drive_frequency", "height", "velocity",
                                                        "resting", "oscillation_amplitude")), CORE_TIME)
        return plant_core.pack(slots, self._film.stepper, self._film.contact.largest_excursion)

    # --- FMU state: the body is in the outputs (saved by the base), the rest is the solver's -----------
    def get_internal_state(self) -> dict:
        return {} if self._film is None else self._film.internal_state()

    def set_internal_state(self, state: dict) -> None:
        if state and self._film is not None:
            self._film.restore(state)


#: ``film_solver``: the solver class each name builds (docs/film_solvers.md).
FILM_SOLVERS = {"harmonic_balance": ReynoldsPlant._harmonic_balance, "time_marching": ReynoldsPlant._time_marching}
