"""Physical plausibility: the ranges outside which a value is a unit slip, not a rig.

Near-field levitation lifts grams to a kilogram or so over tens to hundreds of micrometres (the paper's
rig: 134.7 g at 60-180 um, driven with |a| of a few um at 28.5 kHz, in air). A value far outside these
ranges is almost always grams given as kg, um given as m or kHz as Hz; it is refused with a hint rather
than simulated (a 1 m excitation "levitates" the object 126 km). The ranges are generous: ten times
anything NFAL does.
"""

from __future__ import annotations

import math

import numpy as np

from nfal.errors import InvalidParameterError, span_um

#: Largest clearance (levitation height, rest gap, reference clearance) [m]: squeeze films end at about 1 mm.
MAX_CLEARANCE_M = 5e-3
#: The clearances a levitation rig works at [m], exclusive: heights to identify, design for or tabulate (a
#: calibration file's damping). Below 1 um the surfaces touch; past 1 mm the squeeze film has gone.
WORK_CLEARANCES_M = (1e-6, 1e-3)
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
#: Excitation (and resonance) frequencies [Hz]: Table 1 goes down to 2 kHz, the paper's rig runs at 28.5 kHz;
#: 28.5 is kHz given as Hz.
FREQUENCY_RANGE_HZ = (500.0, 1e6)
#: Dynamic viscosity of the gas [Pa s]: gases are 1e-5 to 3e-5; 18.1 is uPa s given as Pa s.
MAX_VISCOSITY_PA_S = 1e-3
#: Ambient pressure [Pa]: 101.325 is kPa given as Pa, 1013 hPa, 1.013 bar.
PRESSURE_RANGE_PA = (1e4, 1e7)
#: Gravitational acceleration [m/s^2]: 981 is cm/s^2.
MAX_GRAVITY_M_S2 = 100.0
#: Largest time constant of the loop's reference shaping (lift-off pair, reference pair) [s]: the loop settles in
#: 0.1-0.6 s and the lift-off pair is 60 ms; 60 is ms given as s.
MAX_SHAPING_TIME_S = 10.0

_HINTS = {"m": "did you give µm or mm as m?", "kg": "did you give grams as kg?", "m/V": "did you give µm/V as m/V?",
          "Hz": "did you give kHz as Hz?", "Pa": "did you give kPa, hPa or bar as Pa?",
          "Pa.s": "did you give µPa s or mPa s as Pa s?", "s": "did you give ms as s?"}


def require_plausible(name: str, value: float, ceiling: float, unit: str, floor: float = -math.inf) -> float:
    """Return ``value`` if it is at most ``ceiling`` (and at least ``floor``) [unit], else raise
    :class:`InvalidParameterError` with a hint at the likely unit slip. ``value`` is expected finite (checked
    before)."""
    if value > ceiling or value < floor:
        bounds = f"at most {ceiling:g} {unit}" if floor == -math.inf else f"within {floor:g}–{ceiling:g} {unit}"
        raise InvalidParameterError(name, value,
                                    f"{bounds} for a levitation rig ({_HINTS.get(unit, 'check the unit')})")
    return value


def require_clearances(name: str, heights, what: str = "clearances", ndim: int = 1):
    """``heights`` [m] as a float array of ``ndim`` dimensions (0: a float) if each is a clearance of
    :data:`WORK_CLEARANCES_M`, else raise :class:`InvalidParameterError` naming the range and the likely unit slip."""
    low, high = WORK_CLEARANCES_M
    allowed = f"{what} within {span_um(low, high)} ({_HINTS['m']})"
    try:
        values = np.asarray(heights, dtype=float)
    except (TypeError, ValueError):
        raise InvalidParameterError(name, heights, allowed) from None
    if values.ndim != ndim or not np.all((values > low) & (values < high)):
        raise InvalidParameterError(name, heights, allowed)
    return values if ndim else float(values)


def require_clearance(name: str, height: float) -> float:
    """One clearance [m] of :data:`WORK_CLEARANCES_M` (:func:`require_clearances`)."""
    return require_clearances(name, height, "a clearance", ndim=0)
