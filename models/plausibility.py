"""Physical plausibility: the ceilings past which a value is a unit slip, not a rig.

Near-field levitation lifts grams to a kilogram or so over tens to hundreds of micrometres (the paper's
rig: 134.7 g at 60-180 um, driven with |a| of a few um). A value far past these ceilings is almost
always grams given as kg or um given as m; it is refused with a hint rather than simulated (a 1 m
excitation "levitates" the object 126 km). The ceilings are generous: ten times anything NFAL does.
"""

from __future__ import annotations

from nfal.errors import InvalidParameterError

#: Largest clearance (levitation height, rest gap, reference clearance) [m]: squeeze films end at about 1 mm.
MAX_CLEARANCE_M = 5e-3
#: Largest excitation amplitude |a| [m]: piezo-driven surfaces vibrate by a few um (the paper: at most 10 um).
MAX_EXCITATION_M = 1e-4
#: Largest levitated mass [kg]: above Table 1's heaviest case (20 kg on the paper's 50 mm disc), below a
#: mass typed in grams (134.7 g as 134.7 kg).
MAX_MASS_KG = 100.0
#: Largest radius of object and surface [m].
MAX_RADIUS_M = 1.0
#: Largest gain of the voltage -> |a| map [m/V]: the excitation ceiling reached at 10 V (the paper's
#: transducer: 1e-7 m/V, 10 um at 100 V). A 1e300 made every drive voltage 0 V.
MAX_METRES_PER_VOLT = 1e-5

_HINTS = {"m": "did you give um or mm as m?", "kg": "did you give grams as kg?", "m/V": "did you give um/V as m/V?"}


def require_plausible(name: str, value: float, ceiling: float, unit: str) -> float:
    """Return ``value`` if it is at most ``ceiling`` [unit], else raise :class:`InvalidParameterError` with a
    hint at the likely unit slip. ``value`` is expected finite (checked before)."""
    if value > ceiling:
        hint = _HINTS.get(unit, "check the unit")
        raise InvalidParameterError(name, value, f"at most {ceiling:g} {unit} for a levitation rig ({hint})")
    return value
