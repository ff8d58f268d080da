"""Rig parameters (SI) and the paper's non-dimensional groups, eqs. (2) and (14)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from nfal.errors import require_positive

from .plausibility import (FREQUENCY_RANGE_HZ, MAX_CLEARANCE_M, MAX_GRAVITY_M_S2, MAX_MASS_KG, MAX_RADIUS_M,
                           MAX_VISCOSITY_PA_S, PRESSURE_RANGE_PA, require_plausible)

#: Every field's plausible range (:mod:`nfal.models.plausibility`): name -> (ceiling, unit[, floor]).
#: Relative change of the drive frequency that rebuilds a model built for a rig (a plant's, with its state carried
#: over).
FREQUENCY_TOLERANCE = 1e-9


def frequency_changed(frequency: float, built_for: float) -> bool:
    """True when a model built for ``built_for`` [Hz] must be rebuilt for ``frequency`` [Hz]."""
    return abs(frequency - built_for) > FREQUENCY_TOLERANCE * built_for


_RANGES = {"mass": (MAX_MASS_KG, "kg"), "radius": (MAX_RADIUS_M, "m"),
           "frequency": (FREQUENCY_RANGE_HZ[1], "Hz", FREQUENCY_RANGE_HZ[0]), "viscosity": (MAX_VISCOSITY_PA_S, "Pa.s"),
           "ambient_pressure": (PRESSURE_RANGE_PA[1], "Pa", PRESSURE_RANGE_PA[0]),
           "gravity": (MAX_GRAVITY_M_S2, "m/s2"), "reference_clearance": (MAX_CLEARANCE_M, "m")}


@dataclasses.dataclass(frozen=True)
class RigParameters:
    """A levitation rig: levitated object, driving surface and the gas between them (SI units).

    Defaults are the paper's rig (Sec. 3.3): 134.7 g, r0 = 50 mm, 28.5 kHz, in air.
    ``viscosity`` and ``ambient_pressure`` are air at 20 °C and sea level; the paper does not
    give them. ``reference_clearance`` is h0 of eq. (2): it scales the non-dimensional
    variables only, never a physical result (docs/assumptions.md).

    Parameters
    ----------
    mass : float
        Mass of the levitated object m [kg].
    radius : float
        Outer radius r0 of the object and of the driving surface [m].
    frequency : float
        Excitation frequency f = omega / 2 pi [Hz].
    viscosity : float
        Dynamic viscosity of the gas mu [Pa s].
    ambient_pressure : float
        Ambient pressure p_a [Pa].
    gravity : float
        Gravitational acceleration g [m/s^2].
    reference_clearance : float
        Reference clearance h0 of eq. (2) [m].
    """

    mass: float = 0.1347
    radius: float = 0.050
    frequency: float = 28.5e3
    viscosity: float = 1.81e-5
    ambient_pressure: float = 101_325.0
    gravity: float = 9.81
    reference_clearance: float = 100e-6

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):
            object.__setattr__(self, field.name, require_positive(field.name, getattr(self, field.name)))
        for name, plausible in _RANGES.items():
            require_plausible(name, getattr(self, name), *plausible)

    def replace(self, **changes: float) -> "RigParameters":
        """A copy with some fields changed (validated like the original)."""
        return dataclasses.replace(self, **changes)

    @property
    def omega(self) -> float:
        """Angular excitation frequency omega [rad/s]."""
        return 2.0 * math.pi * self.frequency

    def squeeze_number(self, clearance):
        """Squeeze number sigma = 12 mu omega r0^2 / (p_a hbar^2), eq. (2); ``clearance`` hbar in m."""
        clearance = np.asarray(clearance, dtype=float)
        return 12.0 * self.viscosity * self.omega * self.radius**2 / (self.ambient_pressure * clearance**2)

    def clearance_at(self, squeeze_number):
        """The clearance hbar [m] whose squeeze number is ``squeeze_number`` (inverse of eq. 2)."""
        squeeze_number = np.asarray(squeeze_number, dtype=float)
        return np.sqrt(12.0 * self.viscosity * self.omega * self.radius**2 / (self.ambient_pressure * squeeze_number))

    @property
    def film_force_scale(self) -> float:
        """pi r0^2 p_a [N]: the levitation force is this times delta^2 K(sigma), eq. (12)."""
        return math.pi * self.radius**2 * self.ambient_pressure

    @property
    def stiffness_coefficient(self) -> float:
        """C_s* = pi r0^2 p_a / (m omega^2 h0), eq. (14)."""
        return self.film_force_scale / (self.mass * self.omega**2 * self.reference_clearance)

    @property
    def damping_coefficient(self) -> float:
        """C_d = 3 pi mu r0^4 / (2 m omega h0^3), eq. (14)."""
        return (3.0 * math.pi * self.viscosity * self.radius**4
                / (2.0 * self.mass * self.omega * self.reference_clearance**3))

    @property
    def gravity_term(self) -> float:
        """G = g / (omega^2 h0), eq. (14)."""
        return self.gravity / (self.omega**2 * self.reference_clearance)

    def squeeze_film_damping(self, clearance):
        """Viscous damping coefficient 3 pi mu r0^4 / (2 hbar^3) [N s/m] of eq. (6), dimensional."""
        clearance = np.asarray(clearance, dtype=float)
        return 3.0 * math.pi * self.viscosity * self.radius**4 / (2.0 * clearance**3)
