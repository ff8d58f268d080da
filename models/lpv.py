"""The LPV family of eq. (20): eq. (13) linearised about an equilibrium (u_eq, Hbar_eq).

Around an equilibrium of eq. (16) the slow dynamics in the paper's variables (T = omega t,
Hbar = hbar / h0, u = |a| / h0) are

    d^2 dH/dT^2 + alpha1 d dH/dT + alpha0 dH = beta0 du,                          eq. (20)

    alpha0 = -C_s* u_eq^2 (K'(Hbar) / Hbar^2 - 2 K / Hbar^3),
    alpha1 = C_d / Hbar^3,
    beta0  = 2 C_s* u_eq K / Hbar^2,

with K'(Hbar) = dK/dsigma * dsigma/dHbar = -2 sigma / Hbar * dK/dsigma (sigma of eq. 2). In SI the
same model reads  dh'' + alpha1 omega dh' + alpha0 omega^2 dh = beta0 omega^2 d|a|.
With a damping correction f(h) of eq. (6) (identified, or the parametric excess damping) the damping
term is the rig's: alpha1 = f(hbar_eq) C_d / Hbar^3.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import TYPE_CHECKING

import numpy as np

from nfal.errors import InvalidParameterError, span_um

from .calibration import CalibrationFunction, paper_calibration
from .plant import DampingModel, SimplifiedPlant
from .rig import RigParameters

if TYPE_CHECKING:  # python-control is imported where it is used (1.4 s: not in the Controller FMU's set-up)
    import control

logger = logging.getLogger(__name__)

#: Ways of taking dK/dsigma: the calibration's own exact derivative, or a central difference.
DERIVATIVE_SCHEMES = ("exact", "central")
#: Relative step of the central difference in sigma; truncation error ~ (step * sigma)^2 K''' / 6.
CENTRAL_STEP = 1e-4


@dataclasses.dataclass(frozen=True)
class LPVCoefficients:
    """Eq. (20) at one or more equilibria (arrays broadcast like ``height_m``).

    Attributes
    ----------
    height_m : ndarray
        Equilibrium clearance hbar_eq [m].
    excitation_m : ndarray
        Equilibrium excitation norm |a|_eq [m] (eq. 16).
    alpha0, alpha1, beta0 : ndarray
        The non-dimensional coefficients of eq. (20) (time unit 1 / omega).
    omega : float
        Excitation frequency omega [rad/s] that scales time.
    reference_clearance : float
        h0 [m] that scales lengths.
    """

    height_m: np.ndarray
    excitation_m: np.ndarray
    alpha0: np.ndarray
    alpha1: np.ndarray
    beta0: np.ndarray
    omega: float
    reference_clearance: float

    @property
    def stiffness_si(self) -> np.ndarray:
        """alpha0 omega^2 [1/s^2]: linearised film stiffness per unit mass."""
        return self.alpha0 * self.omega**2

    @property
    def damping_si(self) -> np.ndarray:
        """alpha1 omega [1/s]: linearised squeeze-film damping per unit mass."""
        return self.alpha1 * self.omega

    @property
    def input_gain_si(self) -> np.ndarray:
        """beta0 omega^2 [1/s^2]: acceleration [m/s^2] per metre of excitation norm."""
        return self.beta0 * self.omega**2

    def at(self, index) -> "LPVCoefficients":
        """The coefficients of one equilibrium of an array."""
        pick = lambda v: np.asarray(v)[index]  # noqa: E731
        return dataclasses.replace(self, height_m=pick(self.height_m), excitation_m=pick(self.excitation_m),
                                   alpha0=pick(self.alpha0), alpha1=pick(self.alpha1), beta0=pick(self.beta0))

    def transfer_function(self, units: str = "si") -> control.TransferFunction:
        """dHbar / du of eq. (20) (``units="nondimensional"``, variable s per unit T) or
        d hbar / d|a| in SI (``units="si"``, s in rad/s; the two differ only in the time scale)."""
        if np.ndim(self.alpha0) != 0:
            raise InvalidParameterError("LPVCoefficients", "an array", "one equilibrium (use .at(i))")
        import control  # on use: 1.4 s, not in the Controller FMU's set-up

        if units == "nondimensional":
            return control.tf([float(self.beta0)], [1.0, float(self.alpha1), float(self.alpha0)])
        if units == "si":
            return control.tf([float(self.input_gain_si)], [1.0, float(self.damping_si), float(self.stiffness_si)])
        raise InvalidParameterError("units", units, "'si' or 'nondimensional'")


def calibration_slope(calibration: CalibrationFunction, sigma, scheme: str = "exact") -> np.ndarray:
    """dK/dsigma by the calibration's exact derivative or by a central difference.

    ``"central"`` uses (K(s (1 + e)) - K(s (1 - e))) / (2 s e) with e = ``CENTRAL_STEP``: second order,
    relative error ~ 1e-8 for the smooth calibrations here (tested against ``"exact"``). It needs only
    K itself, so it serves any callable calibration.
    """
    sigma = np.asarray(sigma, dtype=float)
    if scheme == "exact":
        return np.asarray(calibration.derivative(sigma), dtype=float)
    if scheme == "central":
        step = CENTRAL_STEP * sigma
        return (np.asarray(calibration(sigma + step)) - np.asarray(calibration(sigma - step))) / (2.0 * step)
    raise InvalidParameterError("derivative", scheme, f"one of {DERIVATIVE_SCHEMES}")


def lpv_coefficients(height_m, rig: RigParameters | None = None, calibration: CalibrationFunction | None = None,
                     *, derivative: str = "exact", damping: DampingModel | None = None) -> LPVCoefficients:
    """alpha0, alpha1, beta0 of eq. (20) at the equilibria of clearance ``height_m`` [m].

    Parameters
    ----------
    height_m : float or array_like
        Equilibrium clearances hbar_eq [m]; their squeeze numbers must lie in the calibration's range.
    rig : RigParameters, optional
        Defaults to the paper's rig.
    calibration : CalibrationFunction, optional
        Any K(sigma) source; defaults to eq. (17).
    derivative : {"exact", "central"}
        How dK/dsigma is taken (see :func:`calibration_slope`).
    damping : ExcessDamping or DampingCorrection, optional
        Correction f(h) of eq. (6)'s damping: alpha1 is multiplied by f(hbar_eq). None: eq. (6).

    Returns
    -------
    LPVCoefficients
    """
    rig = rig or RigParameters()
    calibration = calibration or paper_calibration()
    height = np.asarray(height_m, dtype=float)
    if np.any(~np.isfinite(height)) or np.any(height <= 0):
        raise InvalidParameterError("height_m", height_m, "finite clearances > 0 m")
    sigma = rig.squeeze_number(height)
    if not np.all(calibration.in_range(sigma)):
        low, high = (float(rig.clearance_at(s)) for s in calibration.sigma_range[::-1])
        asked = span_um(float(np.min(height)), float(np.max(height)))
        raise InvalidParameterError(
            "design heights", height_m, f"within {span_um(low, high)}, where {calibration.name} is calibrated: design "
            "within it (nfal design --heights; the Controller's reference_min, reference_max), or calibrate over these "
            "heights (from a rig: a longer identification, nfal identify --equilibria spanning them)", as_shown=asked)
    excitation = SimplifiedPlant(rig, calibration, excess_damping=damping).equilibrium_excitation(height)  # eq. (16)
    H = height / rig.reference_clearance
    u = excitation / rig.reference_clearance
    K = np.asarray(calibration(sigma), dtype=float)
    dK_dH = calibration_slope(calibration, sigma, derivative) * (-2.0 * sigma / H)
    Cs, Cd = rig.stiffness_coefficient, rig.damping_coefficient
    alpha0 = -(dK_dH / H**2 - 2.0 * K / H**3) * Cs * u**2
    alpha1 = Cd / H**3 * (1.0 if damping is None else damping.factor(height))
    beta0 = 2.0 * Cs * u * K / H**2
    if np.any(alpha0 <= 0):
        logger.warning("alpha0 <= 0 at some heights: the open-loop equilibrium is statically unstable there")
    return LPVCoefficients(height, excitation, alpha0, alpha1, beta0, rig.omega, rig.reference_clearance)
