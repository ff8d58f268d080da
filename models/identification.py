"""Identification of a rig from its measured responses (Sec. 3.2.2, 3.3): settling, step fits, damping table.

Pure numerics for ``nfal identify`` (the driving over the link lives in :mod:`nfal.apps.rig_experiments`):

* :func:`settled`: has a measured height stopped moving? A moving-window test on the data: the means of
  the two halves of the last ``window_s`` differ by less than ``drift`` of the height.
* :func:`fit_step`: the damping at one height from a small step of the drive. Eq. (13) linearised about
  the step's mid height is m dh'' + c dh' + k dh = dF, with the force step dF = m g (a2^2 - a1^2) / a_m^2
  (the film force is proportional to |a|^2 at a fixed clearance, eq. 12) and |a| following the drive
  through the transducer's first-order amplitude lag (tau_a = 2 Q / omega_r, models/transducer.py). The
  stiffness comes from the step's own static gain, k = dF / dh_final, so the damping c (the one free
  dynamic parameter) does not lean on the slope of the K fit. The factor over eq. (6) is c / c6(h_mid).
* :func:`damping_table`: per height, the geometric mean of the steps' factors and its 95 % interval, as
  the calibration file's :class:`~nfal.models.damping.DampingCorrection`.
* :func:`simulate_step`: the nonlinear eq. (13) response to the same step, for the model-vs-measurement
  figure (Fig. 6's analogue) before and after the damping correction.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
from scipy import integrate, optimize, stats

from nfal.errors import ConvergenceError, DataFormatError, InvalidParameterError, require_duration, require_positive

from .calibration import CalibrationFunction
from .damping import DampingCorrection
from .measured_calibration import FIT_DEGREE
from .plausibility import require_clearances
from .rig import RigParameters
from .table2 import WORK_RANGE_M
from .transducer import Transducer

#: The transducer's amplitude time constant 2 Q / omega_r [s] (5.6 ms for Q = 500 at 28.5 kHz).
AMPLITUDE_TIME_CONSTANT_S = Transducer().time_constant_s()
#: Default settling test: a 0.4 s window whose halves' means differ by less than 0.25 % of the height.
SETTLE_WINDOW_S = 0.4
SETTLE_DRIFT = 2.5e-3
#: The longest hold or move a plan may allow [s] (a longer one is a typo, and a run that waits for it looks hung).
LONGEST_HOLD_S = 600.0


def _require_distinct(name: str, heights: tuple, spacing: float, minimum: int, why: str) -> None:
    """Refuse ``heights`` [m] with two closer than ``spacing`` (relative) or fewer than ``minimum`` of them."""
    ordered = np.sort(heights)
    close = np.flatnonzero(np.diff(ordered) < spacing * ordered[:-1])
    if close.size:
        pair = ordered[close[0]:close[0] + 2]
        raise InvalidParameterError(name, _micrometres(pair), f"heights at least {spacing * 100:g} % apart (a move "
                                    f"arrives within {spacing * 50:g} % of its height: closer ones are one height)")
    if ordered.size < minimum:
        raise InvalidParameterError(name, _micrometres(ordered), f">= {minimum} distinct heights ({why})")


def _micrometres(heights: np.ndarray) -> str:
    return ", ".join(f"{h * 1e6:.6g}" for h in heights) + " um"


def settled(times: np.ndarray, heights: np.ndarray, window_s: float = SETTLE_WINDOW_S,
            drift: float = SETTLE_DRIFT) -> bool:
    """Whether the height has settled: over the last ``window_s`` of data, the mean of the second half minus
    that of the first is below ``drift`` times the mean height (False while less than a window is recorded)."""
    times, heights = np.asarray(times, dtype=float), np.asarray(heights, dtype=float)
    if times.size < 4 or times[-1] - times[0] < window_s:
        return False
    start = np.searchsorted(times, times[-1] - window_s)
    middle = np.searchsorted(times, times[-1] - window_s / 2)
    first, second = heights[start:middle], heights[middle:]
    if first.size == 0 or second.size == 0:
        return False
    return bool(abs(second.mean() - first.mean()) < drift * abs(heights[start:].mean()))


@dataclasses.dataclass(frozen=True)
class StepFit:
    """The fit of one drive step: mid height [m], damping c [N s/m], stiffness k [N/m], final change [m],
    the factor c / c6(h_mid) over eq. (6), and the RMS residual [m]."""

    height: float
    damping: float
    stiffness: float
    height_change: float
    factor: float
    residual_rms: float


def step_response(times: np.ndarray, mass: float, damping: float, stiffness: float, lag_s: float) -> np.ndarray:
    """Unit step response of k / ((m s^2 + c s + k)(tau_a s + 1)) at ``times`` >= 0 [s] (residues of its poles)."""
    poles = np.roots(np.polymul([mass, damping, stiffness], [lag_s, 1.0])).astype(complex)
    gain = stiffness / (mass * lag_s)
    response = np.ones_like(times, dtype=complex)
    for i, pole in enumerate(poles):
        residue = gain / np.prod(pole - np.delete(poles, i))
        response += residue / pole * np.exp(pole * np.asarray(times))
    return response.real


def fit_step(times: np.ndarray, heights: np.ndarray, excitation_before: float, excitation_after: float,
             rig: RigParameters, lag_s: float = AMPLITUDE_TIME_CONSTANT_S) -> StepFit:
    """Fit eq. (13) linearised to one measured step of |a| (see the module docstring).

    Parameters
    ----------
    times : array
        Sample times [s], 0 at the step (samples before it pin the starting height).
    heights : array
        Measured clearances [m].
    excitation_before, excitation_after : float
        |a| [m] held before and after the step.
    rig : RigParameters
        Mass, gravity and eq. (6)'s damping.
    lag_s : float
        The transducer's amplitude time constant [s] (0: none).
    """
    times, heights = np.asarray(times, dtype=float), np.asarray(heights, dtype=float)
    before = times < 0
    if before.sum() < 3 or (~before).sum() < 20:
        raise DataFormatError(f"a step fit needs samples before and after the step ({before.sum()} and "
                              f"{(~before).sum()})")
    a1, a2 = (require_positive("excitation_before", excitation_before),
              require_positive("excitation_after", excitation_after))
    force_step = rig.mass * rig.gravity * (a2**2 - a1**2) / ((a1**2 + a2**2) / 2)
    start = heights[before].mean()
    lag = max(float(lag_s), 1e-9)
    after = np.clip(times, 0.0, None)

    def model(p: np.ndarray) -> np.ndarray:
        h0, change, log_c = p
        return h0 + change * step_response(after, rig.mass, np.exp(log_c), force_step / change, lag)

    change0 = heights[times > 0.7 * times[-1]].mean() - start
    if change0 * force_step <= 0:
        raise ConvergenceError(f"the step of |a| from {a1:.4g} to {a2:.4g} m moved the height the wrong way "
                               f"({change0 * 1e6:+.3g} um): no equilibrium response to fit")
    c0 = rig.squeeze_film_damping(start)
    fit = optimize.least_squares(lambda p: model(p) - heights, [start, change0, np.log(c0)],
                                 x_scale=[abs(change0), abs(change0), 1.0])
    if not fit.success:
        raise ConvergenceError(f"step fit failed: {fit.message}")
    h0, change, log_c = fit.x
    middle = h0 + change / 2
    damping = float(np.exp(log_c))
    return StepFit(float(middle), damping, float(force_step / change), float(change),
                   float(damping / rig.squeeze_film_damping(middle)), float(np.sqrt(np.mean(fit.fun**2))))


def damping_table(fits_by_height: list[list[StepFit]], confidence: float = 0.95) -> DampingCorrection:
    """One row per height from its repeated step fits: the geometric mean factor and the ``confidence`` interval of
    that mean (Student's t over the steps' spread of log factor). Geometric, since the factor is a multiplier and the
    up and down steps' linearisation errors are nearly reciprocal (about 0.93 and 1.11 at 50 um for +-3 % steps)."""
    rows = []
    for fits in fits_by_height:
        if len(fits) < 2:
            raise InvalidParameterError("steps per height", len(fits), ">= 2 (the interval needs a spread)")
        logs = np.log([fit.factor for fit in fits])
        half = stats.t.ppf(0.5 + confidence / 2, logs.size - 1) * logs.std(ddof=1) / np.sqrt(logs.size)
        mean = logs.mean()
        rows.append((np.mean([fit.height for fit in fits]), *np.exp([mean, mean - half, mean + half])))
    rows.sort()
    return DampingCorrection(*(np.array(column) for column in zip(*rows)))


def simulate_step(times: np.ndarray, start_height: float, excitation_before: float, excitation_after: float,
                  rig: RigParameters, calibration: CalibrationFunction,
                  damping_factor: Callable[[np.ndarray], np.ndarray],
                  lag_s: float = AMPLITUDE_TIME_CONSTANT_S) -> np.ndarray:
    """Eq. (13) (SI) from rest at ``start_height`` [m] after |a| steps from ``excitation_before`` to
    ``excitation_after`` [m] at t = 0 through the amplitude lag, with eq. (6)'s damping times
    ``damping_factor(h)``; heights [m] at ``times`` >= 0."""
    lag = max(float(lag_s), 1e-9)

    def rhs(t, y):
        a = excitation_after + (excitation_before - excitation_after) * np.exp(-t / lag)
        h = max(y[0], 1e-7)
        film = rig.film_force_scale * (a / h) ** 2 * calibration(rig.squeeze_number(h))
        damping = rig.squeeze_film_damping(h) * damping_factor(h)
        return [y[1], (film - damping * y[1]) / rig.mass - rig.gravity]

    times = np.asarray(times, dtype=float)
    solution = integrate.solve_ivp(rhs, (0.0, float(times[-1])), [start_height, 0.0], method="LSODA",
                                   t_eval=times, rtol=1e-8, atol=[1e-12, 1e-10])
    if not solution.success:
        raise ConvergenceError(f"step simulation failed: {solution.message}")
    return solution.y[0]


@dataclasses.dataclass(frozen=True)
class IdentificationPlan:
    """The experiments of ``nfal identify`` and their timing (SI).

    Attributes
    ----------
    equilibrium_heights_m : tuple of float
        Heights approached (closed loop) and then held open loop at the drive found there: the equilibria.
    damping_heights_m : tuple of float
        Heights around which the drive steps by +-``step_fraction`` (``steps`` steps, up and down alternately).
    step_fraction : float
        Relative size of the drive step about the equilibrium drive.
    steps : int
        Fitted steps per damping height (even: as many up as down, whose linearisation errors cancel).
    settle_window_s, settle_drift :
        The settling test (:func:`settled`).
    max_hold_s : float
        A hold not settled by then is a fault (the rig does not settle).
    move_timeout_s : float
        A closed-loop move not within ``move_tolerance`` of its height by then is a fault.
    move_tolerance : float
        Relative height error at which a move has arrived.
    """

    equilibrium_heights_m: tuple = tuple(np.geomspace(47e-6, 210e-6, 12))
    damping_heights_m: tuple = tuple(np.linspace(*WORK_RANGE_M, 8))
    step_fraction: float = 0.03
    steps: int = 6
    settle_window_s: float = SETTLE_WINDOW_S
    settle_drift: float = SETTLE_DRIFT
    max_hold_s: float = 5.0
    move_timeout_s: float = 3.0
    move_tolerance: float = 0.015

    #: Typical times measured against the emulator's default truth [s]: a move, a hold beyond the window.
    TYPICAL_MOVE_S = 0.35
    TYPICAL_EXTRA_HOLD_S = 0.1

    def __post_init__(self) -> None:
        for name in ("equilibrium_heights_m", "damping_heights_m"):
            heights = require_clearances(name, getattr(self, name))
            object.__setattr__(self, name, tuple(float(h) for h in heights))
        for name in ("settle_window_s", "settle_drift", "move_tolerance"):
            require_positive(name, getattr(self, name))
        # heights a move cannot tell apart are one height: a fit through them, or a damping table, has nothing to go on
        _require_distinct("equilibrium_heights_m", self.equilibrium_heights_m, 2 * self.move_tolerance,
                          FIT_DEGREE + 1, f"eq. (17)'s fit has {FIT_DEGREE + 1} coefficients")
        _require_distinct("damping_heights_m", self.damping_heights_m, 2 * self.move_tolerance, 2,
                          "the damping table interpolates between them")
        if not (0 < self.step_fraction <= 0.2):
            raise InvalidParameterError("step_fraction", self.step_fraction, "in (0, 0.2]")
        if not (isinstance(self.steps, int) and self.steps >= 2 and self.steps % 2 == 0):
            raise InvalidParameterError("steps", self.steps, "an even whole number >= 2")
        for name in ("max_hold_s", "move_timeout_s"):
            require_duration(name, getattr(self, name), LONGEST_HOLD_S)
        if self.max_hold_s <= self.settle_window_s:
            raise InvalidParameterError("max_hold_s", self.max_hold_s,
                                        f"> the settling window {self.settle_window_s:g} s")

    def holds(self) -> int:
        """Open-loop holds in the plan: one per equilibrium, 1 + ``steps`` per damping height."""
        return len(self.equilibrium_heights_m) + len(self.damping_heights_m) * (1 + self.steps)

    def moves(self) -> int:
        return len(self.equilibrium_heights_m) + len(self.damping_heights_m)

    def duration_s(self) -> tuple[float, float]:
        """(typical, longest) rig time [s]: typical moves and holds, and every one to its time limit."""
        typical = self.moves() * self.TYPICAL_MOVE_S + self.holds() * (self.settle_window_s + self.TYPICAL_EXTRA_HOLD_S)
        return typical, self.moves() * self.move_timeout_s + self.holds() * self.max_hold_s
