"""nfal's plant contract on top of the slave framework (docs/cosimulation.md, "The contract"): :class:`RigSlave`.

:class:`~nfal.fmus.base.NfalSlave` is generic (declarations with units, guarded calls, FMU state). What the rig's
blocks share is here: the rig parameters (:data:`RIG_PARAMETERS`) and ``calibration`` that SlowPlant,
ReynoldsPlant and the Controller carry, the plant interface every plant declares (SlowPlant, ReynoldsPlant),
its checked inputs, and the models built from them (RigParameters, K(sigma) with a calibration file's damping).
"""

from __future__ import annotations

import math

from nfal.errors import InvalidParameterError, require_amplitude, require_positive
from nfal.fmus.base import NfalSlave
from nfal.models.calibration import (CalibrationFunction, RigCalibration, load_rig_calibration, paper_calibration,
                                     perturbation_calibration)
from nfal.models.excitation import parse_shape
from nfal.models.plant import DEFAULT_REST_GAP
from nfal.models.plausibility import MAX_CLEARANCE_M, MAX_EXCITATION_M, require_plausible
from nfal.models.rig import RigParameters
from nfal.models.table2 import STAIRCASE_LEVELS_M

__all__ = ["RigSlave", "RIG_PARAMETERS", "CALIBRATION_CHOICES", "rig_parameter_values"]

#: The contract's rig parameters: (name, start, unit, description). SlowPlant, ReynoldsPlant and
#: Controller carry them; :meth:`RigSlave.build_rig` turns them into a RigParameters.
RIG_PARAMETERS: tuple[tuple[str, float, str, str], ...] = (
    ("mass", RigParameters.mass, "kg", "mass m of the levitated object"),
    ("radius", RigParameters.radius, "m", "radius r0 of the object and of the driving surface"),
    ("nominal_frequency", RigParameters.frequency, "Hz", "nominal excitation frequency f (sets sigma with the "
     "clearance, eq. 2)"),
    ("viscosity", RigParameters.viscosity, "Pa.s", "dynamic viscosity mu of the gas"),
    ("ambient_pressure", RigParameters.ambient_pressure, "Pa", "ambient pressure p_a"),
    ("gravity", RigParameters.gravity, "m/s2", "gravitational acceleration g"),
)


def rig_parameter_values(rig: RigParameters) -> dict[str, float]:
    """The values of :data:`RIG_PARAMETERS` that describe ``rig`` (the inverse of :meth:`RigSlave.build_rig`)."""
    return {name: rig.frequency if name == "nominal_frequency" else getattr(rig, name) for name, *_ in RIG_PARAMETERS}


#: ``calibration`` values besides a path to a calibration JSON written by ``nfal calibrate``.
CALIBRATION_CHOICES = ("paper", "perturbation")


class RigSlave(NfalSlave):
    """An :class:`~nfal.fmus.base.NfalSlave` of the rig's loop: declares the rig parameters and the plant interface,
    checks their values and builds the models from them."""

    def add_rig_parameters(self) -> None:
        """Declare the contract's rig parameters (:data:`RIG_PARAMETERS`) and ``calibration``."""
        for name, start, unit, description in RIG_PARAMETERS:
            self.add_parameter(name, start, unit=unit, description=description)
        self.add_parameter("calibration", "paper", description="K(sigma): 'paper' = eq. (17), 'perturbation' "
                           "(eqs. 9-11 for the paper's excitation form), 'perturbation:SHAPE' (the same for 'piston', "
                           "'plate:N' or a shape CSV), or the path of a calibration JSON (with its damping correction "
                           "of eq. (6), if it has one)")

    def add_plant_interface(self) -> None:
        """Declare what every plant shares (contract: SlowPlant, ReynoldsPlant, a hardware proxy): inputs
        ``excitation_amplitude`` and ``drive_frequency``; outputs ``height``, ``velocity``, ``resting``;
        parameters ``initial_height``, ``initial_velocity``, ``rest_gap`` and the rig."""
        self.add_input("excitation_amplitude", 0.0, unit="m", description="excitation amplitude |a| (norm of eq. 7)")
        self.add_input("drive_frequency", RigParameters.frequency, unit="Hz",
                       description="drive frequency f; sigma scales with it (eq. 2)")
        self.add_output("height", unit="m", description="clearance hbar (slow, averaged over an excitation period)")
        self.add_output("velocity", unit="m/s", description="d hbar / dt")
        self.add_output("resting", kind=bool, description="true while the object rests on the surface (at rest_gap)")
        self.add_parameter("initial_height", STAIRCASE_LEVELS_M[0], unit="m", description="clearance at release")
        self.add_parameter("initial_velocity", 0.0, unit="m/s", description="velocity at release")
        self.add_parameter("rest_gap", DEFAULT_REST_GAP, unit="m",
                           description="closest approach: the object lands and rests here")
        self.add_rig_parameters()

    def checked_release(self) -> tuple[float, float, float]:
        """(rest_gap, initial_height, initial_velocity) of the plant interface, checked."""
        rest_gap = require_plausible("rest_gap", require_positive("rest_gap", self.rest_gap), MAX_CLEARANCE_M, "m")
        height = require_positive("initial_height", self.initial_height)
        require_plausible("initial_height", height, MAX_CLEARANCE_M, "m")
        if height < rest_gap:
            raise InvalidParameterError("initial_height", height, f">= rest_gap = {rest_gap:g} m")
        if not math.isfinite(self.initial_velocity):
            raise InvalidParameterError("initial_velocity", self.initial_velocity, "a finite number (m/s)")
        return rest_gap, height, float(self.initial_velocity)

    def checked_excitation(self) -> float:
        """The ``excitation_amplitude`` input [m], checked."""
        value = require_amplitude("excitation_amplitude", self.excitation_amplitude)
        return require_plausible("excitation_amplitude", value, MAX_EXCITATION_M, "m")

    def checked_frequency(self) -> float:
        """The ``drive_frequency`` input [Hz], checked."""
        return require_positive("drive_frequency", self.drive_frequency)

    # --- shared model builders ---------------------------------------------------------------------
    def build_rig(self, frequency: float | None = None) -> RigParameters:
        """RigParameters from the rig parameters (the excitation at ``frequency`` [Hz], default nominal)."""
        values = {name: require_positive(name, getattr(self, name)) for name, *_ in RIG_PARAMETERS}
        nominal = values.pop("nominal_frequency")
        source = "nominal_frequency" if frequency is None else "drive_frequency"
        frequency = nominal if frequency is None else require_positive("frequency", frequency)
        try:
            return RigParameters(frequency=frequency, **values)
        except InvalidParameterError as exc:  # named as this FMU's variable
            raise InvalidParameterError(source, exc.value, exc.allowed) if exc.name == "frequency" else exc from None

    def build_calibration(self) -> CalibrationFunction:
        """K(sigma) of :meth:`build_rig_calibration` for this slave's rig."""
        return self.build_rig_calibration(self.build_rig()).calibration

    def build_rig_calibration(self, rig: RigParameters) -> RigCalibration:
        """K(sigma) named by ``calibration`` and a calibration file's damping correction (if any): 'paper' (eq. 17),
        'perturbation' (eqs. 9-12 for the Fig. 3 stand-in form), 'perturbation:SHAPE' (the same for an excitation
        form as ``parse_shape`` reads it: 'piston', 'plate:N', a CSV path), or a calibration JSON path (a file
        identified on another rig than ``rig`` is refused)."""
        spec = str(self.calibration).strip()
        if spec == "paper":
            return RigCalibration(paper_calibration())
        if spec == "perturbation" or spec.startswith("perturbation:"):
            return RigCalibration(perturbation_calibration(parse_shape(spec.partition(":")[2] or "paper")))
        if not spec:
            raise InvalidParameterError("calibration", spec, f"one of {CALIBRATION_CHOICES}, 'perturbation:SHAPE' or a "
                                        "calibration JSON path")
        return load_rig_calibration(spec, rig)
