"""PID design by double-pair pole placement, eqs. (21)-(24), its gain schedule and a fixed design.

The local closed loop of eqs. (20)-(22) is eq. (23),

    dHbar / dr = beta0 (omega_L + s)(k_p s + k_i) / (s^4 + C3 s^3 + C2 s^2 + C1 s + C0),

with C0..C3 of eq. (24). Critical damping in pairs means the denominator is (s + p1)^2 (s + p2)^2:

    C3 = 2 (p1 + p2)            C2 = (p1 + p2)^2 + 2 p1 p2
    C1 = 2 p1 p2 (p1 + p2)      C0 = (p1 p2)^2.

C3 = alpha1 + omega_L holds no gain, so the pole sum p1 + p2 = (alpha1 + omega_L) / 2 is set by the
plant's squeeze-film damping and the derivative filter alone. The other three equations are linear in
(k_p, k_i, k_d) once the product q = p1 p2 is chosen: one degree of freedom is left, and the closed
loop's cut-off fixes it. Here the cut-off is the -3 dB bandwidth of eq. (23) (|T(j w)| = 1/sqrt(2),
T(0) = 1), solved for the slow pole p1 on the branch k_p >= 0 (docs/controller.md has the derivation
and why that branch).

All design arithmetic is in the paper's non-dimensional time T = omega t; :class:`PIDDesign` and the
schedules also give the gains in SI: k_p [m/m], k_i [1/s], k_d [s].
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
from typing import TYPE_CHECKING

import numpy as np
import scipy

from nfal.errors import ConvergenceError, InvalidParameterError, require_positive

from .calibration import CalibrationFunction, paper_calibration
from .lpv import LPVCoefficients, lpv_coefficients
from .plant import DampingModel
from .rig import RigParameters
from . import sampled_design
from .disk_cache import cached_array, digest, source_digest
from .sampled_design import SampledLoop
from .scalar_spline import ScalarSpline
from .table2 import CLOSED_LOOP_CUTOFF_HZ, FILTER_CUTOFF_HZ, WORK_RANGE_M

if TYPE_CHECKING:  # python-control costs 1.4 s to import: the Controller FMU's design does not use it
    import control

logger = logging.getLogger(__name__)

_HALF_POWER = 1.0 / math.sqrt(2.0)


@dataclasses.dataclass(frozen=True)
class DesignSpec:
    """The two design choices left by double-pair placement (Table 2).

    Parameters
    ----------
    closed_loop_cutoff_hz : float
        -3 dB bandwidth of the local closed loop, eq. (23) [Hz].
    filter_cutoff_hz : float
        Cut-off omega_LPF / 2 pi of the differentiator's low-pass filter, eq. (22) [Hz].
    sample_rate_hz : float or None
        None: place the poles of the continuous loop, eqs. (23)-(24) (the paper). A rate [Hz]: place
        those of the loop sampled at that rate, as the digital law runs it (:mod:`nfal.models.sampled_design`).
    reference_zero : float or None
        The law's reference zero rho (:mod:`nfal.models.control_law`): a sampled design then reaches its
        cut-off with the reference passing through that filter, as the law runs it. None: without it.
    """

    closed_loop_cutoff_hz: float = CLOSED_LOOP_CUTOFF_HZ
    filter_cutoff_hz: float = FILTER_CUTOFF_HZ
    sample_rate_hz: float | None = None
    reference_zero: float | None = None

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if value is not None or field.name not in ("sample_rate_hz", "reference_zero"):  # None: not asked for
                object.__setattr__(self, field.name, require_positive(field.name, value))

    def omega_lpf(self, rig: RigParameters) -> float:
        """omega_LPF in the paper's time unit 1 / omega (non-dimensional)."""
        return 2.0 * math.pi * self.filter_cutoff_hz / rig.omega

    def omega_cutoff(self, rig: RigParameters) -> float:
        """The closed-loop cut-off in the paper's time unit (non-dimensional)."""
        return 2.0 * math.pi * self.closed_loop_cutoff_hz / rig.omega


@dataclasses.dataclass(frozen=True)
class PIDDesign:
    """The gains of eqs. (21)-(22) designed at one equilibrium.

    Non-dimensional attributes are the paper's (time unit 1 / omega); the ``*_si`` properties convert.

    Attributes
    ----------
    lpv : LPVCoefficients
        Eq. (20) at the design height.
    omega_lpf : float
        Filter cut-off (non-dimensional).
    kp, ki, kd : float
        The paper's gains k_p, k_i, k_d (non-dimensional).
    slow_pole, fast_pole : float
        p1 <= p2: the closed loop's poles are -p1 and -p2, each double (non-dimensional); for a sampled
        design the discrete loop's are exp(-p1 T_s) and exp(-p2 T_s).
    bandwidth : float
        -3 dB bandwidth reached (non-dimensional), of eq. (23) or of the sampled loop.
    sample_step : float or None
        omega T_s of a sampled design (:mod:`nfal.models.sampled_design`); None: a continuous one.

    :meth:`closed_loop` and :meth:`loop_poles` are the continuous loop's (eq. 23) with these gains; the
    loop a sampled design realises is :class:`~nfal.models.sampled_design.SampledLoop`.
    """

    lpv: LPVCoefficients
    omega_lpf: float
    kp: float
    ki: float
    kd: float
    slow_pole: float
    fast_pole: float
    bandwidth: float
    sample_step: float | None = None

    @property
    def height_m(self) -> float:
        return float(self.lpv.height_m)

    @property
    def kp_si(self) -> float:
        """k_p [m of excitation per m of height error] (same number as the paper's)."""
        return self.kp

    @property
    def ki_si(self) -> float:
        """k_i omega [1/s]."""
        return self.ki * self.lpv.omega

    @property
    def kd_si(self) -> float:
        """k_d / omega [s]."""
        return self.kd / self.lpv.omega

    @property
    def slow_pole_hz(self) -> float:
        return self.slow_pole * self.lpv.omega / (2.0 * math.pi)

    @property
    def fast_pole_hz(self) -> float:
        return self.fast_pole * self.lpv.omega / (2.0 * math.pi)

    @property
    def bandwidth_hz(self) -> float:
        return self.bandwidth * self.lpv.omega / (2.0 * math.pi)

    def denominator(self) -> np.ndarray:
        """[1, C3, C2, C1, C0] of eq. (24), non-dimensional."""
        return characteristic_polynomial(self.lpv, self.kp, self.ki, self.kd, self.omega_lpf)

    def intended_poles(self, units: str = "si") -> np.ndarray:
        """The placed poles [-p1, -p1, -p2, -p2] in rad/s (``"si"``) or per unit T."""
        poles = -np.array([self.slow_pole, self.slow_pole, self.fast_pole, self.fast_pole])
        return poles * _time_scale(self.lpv, units)

    def closed_loop(self, units: str = "si") -> control.TransferFunction:
        """Eq. (23) as a transfer function (s in rad/s for ``"si"``)."""
        return _rescale(closed_loop_transfer_function(self.lpv, self.kp, self.ki, self.kd, self.omega_lpf),
                        _time_scale(self.lpv, units))

    def loop_poles(self, units: str = "si") -> np.ndarray:
        """Poles of the loop assembled block by block with python-control: plant of eq. (20) in series
        with k_p + k_i / s + k_d omega_L s / (s + omega_L), unity feedback. The derivative acting on the
        height rather than the error changes the zeros of eq. (23), not its poles; this check is
        independent of eq. (24)'s algebra."""
        import control  # on use: 1.4 s, not in the Controller FMU's set-up

        scale = _time_scale(self.lpv, units)
        plant = _rescale(self.lpv.transfer_function("nondimensional"), scale)
        s = control.tf("s")
        wl, ki, kd = self.omega_lpf * scale, self.ki * scale, self.kd / scale
        controller = self.kp + ki / s + control.tf([kd * wl, 0.0], [1.0, wl])  # PI + filtered D
        loop = control.feedback(control.ss(plant) * control.ss(controller), 1)  # 4 states, no cancellation
        return np.sort_complex(control.poles(loop))


def characteristic_polynomial(lpv: LPVCoefficients, kp, ki, kd, omega_lpf: float) -> np.ndarray:
    """[1, C3, C2, C1, C0] of eq. (24) (non-dimensional; ``lpv`` at one equilibrium)."""
    a0, a1, b0, wl = float(lpv.alpha0), float(lpv.alpha1), float(lpv.beta0), omega_lpf
    return np.array([1.0, a1 + wl, a1 * wl + a0 + b0 * kp + b0 * wl * kd, a0 * wl + b0 * wl * kp + b0 * ki,
                     b0 * wl * ki])


def closed_loop_transfer_function(lpv: LPVCoefficients, kp, ki, kd, omega_lpf: float) -> control.TransferFunction:
    """Eq. (23), non-dimensional."""
    import control  # on use: 1.4 s, not in the Controller FMU's set-up

    b0 = float(lpv.beta0)
    numerator = b0 * np.array([kp, omega_lpf * kp + ki, omega_lpf * ki])
    return control.tf(numerator, characteristic_polynomial(lpv, kp, ki, kd, omega_lpf))


def gains_for_pole_product(lpv: LPVCoefficients, pole_product: float, omega_lpf: float) -> tuple[float, float, float]:
    """(k_p, k_i, k_d) that make eq. (24) equal (s + p1)^2 (s + p2)^2 with p1 p2 = ``pole_product``.

    With S = p1 + p2 = (alpha1 + omega_L) / 2 (the C3 equation) and q = p1 p2:
    k_i = q^2 / (beta0 omega_L);  k_p = (2 q S - alpha0 omega_L - beta0 k_i) / (beta0 omega_L);
    k_d = (S^2 + 2 q - alpha1 omega_L - alpha0 - beta0 k_p) / (beta0 omega_L).
    """
    a0, a1, b0, wl, q = float(lpv.alpha0), float(lpv.alpha1), float(lpv.beta0), omega_lpf, pole_product
    total = 0.5 * (a1 + wl)
    ki = q**2 / (b0 * wl)
    kp = (2.0 * q * total - a0 * wl - b0 * ki) / (b0 * wl)
    kd = (total**2 + 2.0 * q - a1 * wl - a0 - b0 * kp) / (b0 * wl)
    return kp, ki, kd


def _closed_loop_gain(lpv: LPVCoefficients, slow: float, omega_lpf: float, frequency) -> np.ndarray:
    """|T(j w)| of eq. (23) with the double pairs at -slow and -(S - slow)."""
    total = 0.5 * (float(lpv.alpha1) + omega_lpf)
    kp, ki, _ = gains_for_pole_product(lpv, slow * (total - slow), omega_lpf)
    s = 1j * np.asarray(frequency, dtype=float)
    return np.abs(float(lpv.beta0) * (s + omega_lpf) * (kp * s + ki) / ((s + slow) ** 2 * (s + total - slow) ** 2))


def closed_loop_bandwidth(lpv: LPVCoefficients, slow_pole: float, omega_lpf: float) -> float:
    """Lowest frequency (non-dimensional) where |T(j w)| of eq. (23) falls through 1/sqrt(2)."""
    total = 0.5 * (float(lpv.alpha1) + omega_lpf)
    grid = np.geomspace(1e-4 * slow_pole, 10.0 * total, 2000)
    gain = _closed_loop_gain(lpv, slow_pole, omega_lpf, grid)
    below = np.flatnonzero(gain < _HALF_POWER)
    if below.size == 0 or below[0] == 0:
        raise ConvergenceError(f"no -3 dB crossing of eq. (23) found for p1 = {slow_pole:.4g}")
    i = below[0]
    return float(scipy.optimize.brentq(lambda w: _closed_loop_gain(lpv, slow_pole, omega_lpf, w) - _HALF_POWER,
                                 grid[i - 1], grid[i], xtol=1e-14, rtol=1e-12))


def design_at(lpv: LPVCoefficients, spec: DesignSpec, rig: RigParameters) -> PIDDesign:
    """Double-pair design at one equilibrium: of eqs. (23)-(24) (the module docstring), or of the sampled
    loop when ``spec.sample_rate_hz`` is set (:mod:`nfal.models.sampled_design`)."""
    wl = spec.omega_lpf(rig)
    total = 0.5 * (float(lpv.alpha1) + wl)
    if spec.sample_rate_hz is None:
        def placed(slow):
            return (*gains_for_pole_product(lpv, slow * (total - slow), wl), total - slow)
        bandwidth, step = (lambda slow: closed_loop_bandwidth(lpv, slow, wl)), None
    else:
        step = rig.omega / spec.sample_rate_hz
        loop = SampledLoop(lpv, wl, step, spec.reference_zero)

        def placed(slow):
            kp, ki, kd, fast = loop.gains(slow)
            with np.errstate(invalid="ignore", divide="ignore"):
                return kp, ki, kd, np.where((fast > 0.0) & (fast < 1.0), -np.log(fast) / step, math.nan)
        bandwidth = loop.bandwidth
    grid = np.geomspace(1e-7 * total, 0.5 * total, 400)
    if step is not None and not np.any(np.isfinite(placed(grid)[0])):
        # the fast pair cannot be a real double pole: seen when the filter's forward-Euler pole 1 - T_s omega_L < 0
        raise InvalidParameterError("sample_rate_hz", spec.sample_rate_hz,
                                    "fast enough for a critically damped sampled loop at "
                                    f"{float(lpv.height_m) * 1e6:.1f} um with the {spec.filter_cutoff_hz:g} Hz filter "
                                    f"(here T_s omega_L = {step * wl:.2f}; Table 2's 2 kHz and 300 Hz give 0.94), "
                                    "or the continuous placement")
    slow = _slow_pole_for_cutoff(lambda p: placed(p)[0], bandwidth, grid, spec.omega_cutoff(rig), spec, lpv, rig)
    kp, ki, kd, fast = (float(v) for v in placed(slow))
    if not math.isfinite(fast):
        raise ConvergenceError(f"the sampled design at {float(lpv.height_m) * 1e6:.1f} um has no fast pair in (0, 1)")
    return PIDDesign(lpv, wl, kp, ki, kd, slow, fast, bandwidth(slow), step)


def _slow_pole_for_cutoff(kp_of, bandwidth_of, grid: np.ndarray, cutoff: float, spec: DesignSpec,
                          lpv: LPVCoefficients, rig: RigParameters) -> float:
    """The slow pole p1 whose design reaches the -3 dB ``cutoff``, on the branch k_p >= 0 (docs/controller.md):
    from the p1 where k_p = 0 up to the first grid point whose bandwidth exceeds the cut-off, by Brent's method."""
    height_um = float(lpv.height_m) * 1e6
    kp = np.asarray(kp_of(grid), dtype=float)  # vectorised over the grid
    rising = np.flatnonzero((kp[:-1] < 0) & (kp[1:] >= 0))
    if rising.size == 0:
        raise ConvergenceError(f"no slow pole gives k_p >= 0 at {height_um:.1f} um")
    i = rising[0]
    slow_min = scipy.optimize.brentq(lambda p: float(kp_of(p)), grid[i], grid[i + 1], xtol=1e-16, rtol=1e-13)
    candidates = np.concatenate([[slow_min * (1 + 1e-9)], grid[i + 1:]])
    for lower, upper in zip(candidates[:-1], candidates[1:]):
        if bandwidth_of(upper) >= cutoff:
            break
    else:
        raise InvalidParameterError("closed_loop_cutoff_hz", spec.closed_loop_cutoff_hz,
                                    f"reachable with double pole pairs at {height_um:.1f} um")
    if bandwidth_of(lower) > cutoff:
        reachable = bandwidth_of(lower) * rig.omega / (2 * math.pi)
        raise InvalidParameterError("closed_loop_cutoff_hz", spec.closed_loop_cutoff_hz,
                                    f">= {reachable:.3g} Hz at {height_um:.1f} um (the k_p = 0 design)")
    return float(scipy.optimize.brentq(lambda p: bandwidth_of(p) - cutoff, lower, upper, xtol=1e-16, rtol=1e-12))


def design_pid(height_m: float, rig: RigParameters | None = None, calibration: CalibrationFunction | None = None,
               spec: DesignSpec | None = None, *, derivative: str = "exact",
               damping: DampingModel | None = None) -> PIDDesign:
    """The local PID of eqs. (21)-(24) designed at the equilibrium of clearance ``height_m`` [m].

    Parameters
    ----------
    height_m : float
        Design clearance [m].
    rig, calibration : optional
        Design model; default the paper's rig and eq. (17).
    spec : DesignSpec, optional
        Cut-offs and the loop designed for; default Table 2 (10 Hz closed loop, 300 Hz filter), continuous.
    derivative : {"exact", "central"}
        How dK/dsigma enters alpha0 (:func:`nfal.models.lpv.calibration_slope`).
    damping : ExcessDamping or DampingCorrection, optional
        Correction of eq. (6)'s damping (an identified rig's); it enters alpha1 of eq. (20).
    """
    rig = rig or RigParameters()
    if np.ndim(height_m) != 0:
        raise InvalidParameterError("height_m", height_m, "one clearance [m] (use design_schedule for many)")
    lpv = lpv_coefficients(float(height_m), rig, calibration or paper_calibration(), derivative=derivative,
                           damping=damping)
    return design_at(lpv, spec or DesignSpec(), rig)


def _gain_spline(knots: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """The coefficients (``PPoly.c``) of the not-a-knot cubic spline of ``gains`` (one row per knot) over ``knots``,
    kept in the user-wide cache: a Controller that finds them there imports no scipy.interpolate (which brings
    scipy.optimize, .special, .linalg and .sparse: ``python bench/bench_startup.py``)."""
    def check(stored: np.ndarray) -> None:
        if stored.shape != (4, knots.size - 1, gains.shape[1]) or not np.all(np.isfinite(stored)):
            raise ValueError(f"a stored gain spline of shape {stored.shape}")

    return cached_array("gain_splines", digest("gain-spline", scipy.__version__, knots, gains),
                        lambda: scipy.interpolate.CubicSpline(knots, gains, axis=0).c, check=check)


class GainSchedule:
    """k_p, k_i, k_d over a table of design heights, interpolated by a C2 cubic spline in Hbar.

    The paper's stability argument (Sec. 4.1) needs gains continuously differentiable in the
    scheduling variable Hbar; a not-a-knot cubic spline through the designed points is C2. Outside
    the table the scheduling variable is clamped to the nearer end (gains held).

    Parameters
    ----------
    designs : sequence of PIDDesign
        Designs at strictly increasing heights (at least 4).
    """

    def __init__(self, designs) -> None:
        designs = tuple(designs)
        if len(designs) < 4:
            raise InvalidParameterError("designs", len(designs), "at least 4 design heights")
        heights = np.array([d.height_m for d in designs])
        if np.any(np.diff(heights) <= 0):
            raise InvalidParameterError("designs", heights, "strictly increasing design heights")
        self.designs = designs
        self.heights_m = heights
        self.omega = designs[0].lpv.omega
        self.reference_clearance = designs[0].lpv.reference_clearance
        self.omega_lpf = designs[0].omega_lpf
        self._knots = heights / self.reference_clearance
        self._coefficients = _gain_spline(self._knots, np.array([[d.kp, d.ki, d.kd] for d in designs]))
        self._scalar_gains = ScalarSpline(self._knots, self._coefficients)  # for law_terms
        self._slow_times_s = [1.0 / (d.slow_pole * d.lpv.omega) for d in designs]
        self.name = "gain-scheduled"

    @functools.cached_property
    def _spline(self):
        """The spline as scipy's ``PPoly``, for the vectorised views (the 2 kHz law needs none: :meth:`law_terms`)."""
        return scipy.interpolate.PPoly(self._coefficients, self._knots)

    @functools.cached_property
    def _slope(self):
        return self._spline.derivative()

    @property
    def height_range_m(self) -> tuple[float, float]:
        return float(self.heights_m[0]), float(self.heights_m[-1])

    def _H(self, height_m) -> np.ndarray:
        return np.clip(np.asarray(height_m, dtype=float), *self.height_range_m) / self.reference_clearance

    def gains_nondimensional(self, height_m) -> np.ndarray:
        """The paper's (k_p, k_i, k_d) at clearance ``height_m`` [m]; shape (..., 3)."""
        return self._spline(self._H(height_m))

    def gains_si(self, height_m) -> np.ndarray:
        """(k_p [m/m], k_i [1/s], k_d [s]) at clearance ``height_m`` [m]; shape (..., 3)."""
        return self.gains_nondimensional(height_m) * np.array([1.0, self.omega, 1.0 / self.omega])

    def law_terms(self, height_m: float) -> tuple[float, float, float, float]:
        """What the discrete law needs at one clearance [m], in plain floats (it runs every 0.5 ms): :meth:`gains_si`
        and 1 / p1 [s], the slow double pole's time constant (interpolated linearly); held outside the table."""
        i, dx = self._scalar_gains.piece(height_m / self.reference_clearance)
        kp, ki, kd = self._scalar_gains.values_in(i, dx)
        knots, slow = self._scalar_gains.knots, self._slow_times_s
        slow_time = slow[i] + (slow[i + 1] - slow[i]) * dx / (knots[i + 1] - knots[i])
        return kp, ki * self.omega, kd / self.omega, slow_time

    def law_table(self) -> dict:
        """What :meth:`law_terms` computes from, for the compiled loop (``firmware/loop/nfal_law.h``): the knots in
        Hbar, the spline's pieces, 1 / p1 at each knot [s], the reference clearance [m] and omega [rad/s]."""
        return {"knot": self._scalar_gains.knots, "pieces": self._scalar_gains.pieces,
                "slow_time_s": list(self._slow_times_s), "reference_clearance_m": float(self.reference_clearance),
                "omega": float(self.omega)}

    def slope_nondimensional(self, height_m) -> np.ndarray:
        """d(k_p, k_i, k_d)/dHbar (zero outside the table, where the gains are held)."""
        inside = (np.asarray(height_m) >= self.heights_m[0]) & (np.asarray(height_m) <= self.heights_m[-1])
        return np.where(np.asarray(inside)[..., None], self._slope(self._H(height_m)), 0.0)


class FixedGains:
    """A linear (unscheduled) controller: the gains of one :class:`PIDDesign` at every height."""

    def __init__(self, design: PIDDesign) -> None:
        self.design = design
        self.omega = design.lpv.omega
        self.reference_clearance = design.lpv.reference_clearance
        self.omega_lpf = design.omega_lpf
        self._gains = np.array([design.kp, design.ki, design.kd])
        self._law_terms = (*(float(g) for g in self.gains_si(design.height_m)), 1.0 / (design.slow_pole * self.omega))
        self.name = f"linear at {design.height_m * 1e6:.0f} um"

    @property
    def height_range_m(self) -> tuple[float, float]:
        return self.design.height_m, self.design.height_m

    def gains_nondimensional(self, height_m) -> np.ndarray:
        """The paper's (k_p, k_i, k_d), the same at every clearance; shape (..., 3)."""
        return np.broadcast_to(self._gains, np.shape(height_m) + (3,)).copy()

    def gains_si(self, height_m) -> np.ndarray:
        """(k_p [m/m], k_i [1/s], k_d [s]); shape (..., 3)."""
        return self.gains_nondimensional(height_m) * np.array([1.0, self.omega, 1.0 / self.omega])

    def law_terms(self, height_m: float) -> tuple[float, float, float, float]:
        """:meth:`gains_si` and 1 / p1 [s] of the design, as plain floats, at every clearance."""
        return self._law_terms

    def law_table(self) -> dict:
        """:meth:`law_terms`, for the compiled loop (``firmware/loop/nfal_law.h``)."""
        return dict(zip(("fixed_kp", "fixed_ki", "fixed_kd", "fixed_slow_time_s"), self._law_terms))


def design_schedule(heights_m=None, rig: RigParameters | None = None, calibration: CalibrationFunction | None = None,
                    spec: DesignSpec | None = None, *, derivative: str = "exact",
                    damping: DampingModel | None = None) -> GainSchedule:
    """Designs at every height of ``heights_m`` [m] (default 50-200 um every 5 um) as a :class:`GainSchedule`
    (arguments as :func:`design_pid`)."""
    if heights_m is None:
        heights_m = np.linspace(*WORK_RANGE_M, 31)
    rig, calibration, spec = rig or RigParameters(), calibration or paper_calibration(), spec or DesignSpec()
    heights = np.sort(np.asarray(heights_m, dtype=float).ravel())
    lpv = lpv_coefficients(heights, rig, calibration, derivative=derivative, damping=damping)
    return GainSchedule(_designs_at(lpv, spec, rig))


@functools.cache
def _design_source() -> bytes:
    """The code a cached design depends on (read once a process)."""
    return source_digest(__file__, sampled_design.__file__)


#: What a design is beyond its inputs, as :func:`_designs_at` keeps it: (k_p, k_i, k_d, p1, p2, bandwidth).
_DESIGN_NUMBERS = ("kp", "ki", "kd", "slow_pole", "fast_pole", "bandwidth")


def _designs_at(lpv: LPVCoefficients, spec: DesignSpec, rig: RigParameters) -> list[PIDDesign]:
    """:func:`design_at` at every equilibrium of ``lpv``, kept in the user-wide cache: a design is a pure function
    of the equilibrium, the spec, the rig and this code (2 s for Table 2's 31 heights; an FMU designs at each
    set-up)."""
    points = [lpv.at(i) for i in range(np.size(lpv.height_m))]

    def design() -> np.ndarray:
        designs = [design_at(point, spec, rig) for point in points]
        logger.info("designed %d PIDs over %.1f-%.1f um", len(designs), designs[0].lpv.height_m * 1e6,
                    designs[-1].lpv.height_m * 1e6)
        return np.array([[getattr(d, name) for name in _DESIGN_NUMBERS] for d in designs], dtype=float)

    def check(stored: np.ndarray) -> None:
        if stored.shape != (len(points), len(_DESIGN_NUMBERS)) or not np.all(np.isfinite(stored)):
            raise ValueError(f"a stored design of shape {stored.shape}")

    key = digest("pid-design", _design_source(), dataclasses.astuple(spec),
                 dataclasses.astuple(rig), *(np.asarray(getattr(lpv, name), dtype=float)
                                             for name in ("height_m", "excitation_m", "alpha0", "alpha1", "beta0")))
    numbers = cached_array("pid_designs", key, design, check=check)
    step = None if spec.sample_rate_hz is None else rig.omega / spec.sample_rate_hz
    return [PIDDesign(point, spec.omega_lpf(rig), *(float(v) for v in row), step)
            for point, row in zip(points, numbers)]


def fixed_design(height_m: float, rig: RigParameters | None = None, calibration: CalibrationFunction | None = None,
                 spec: DesignSpec | None = None, *, derivative: str = "exact",
                 damping: DampingModel | None = None) -> FixedGains:
    """The linear controller of Sec. 4.1's comparison: the design at ``height_m`` [m] used everywhere."""
    return FixedGains(design_pid(height_m, rig, calibration, spec, derivative=derivative, damping=damping))


def _time_scale(lpv: LPVCoefficients, units: str) -> float:
    if units == "si":
        return lpv.omega
    if units == "nondimensional":
        return 1.0
    raise InvalidParameterError("units", units, "'si' or 'nondimensional'")


def _rescale(system: control.TransferFunction, scale: float) -> control.TransferFunction:
    """G(s / scale): the same system with time measured in units 1 / scale shorter."""
    import control  # on use: 1.4 s, not in the Controller FMU's set-up

    num, den = (np.atleast_1d(np.squeeze(p)) for p in control.tfdata(system))
    n, d = len(num) - 1, len(den) - 1
    num = num * scale ** (d - n + np.arange(n + 1))
    den = den * scale ** np.arange(d + 1)
    return control.tf(num / den[0], den / den[0])
