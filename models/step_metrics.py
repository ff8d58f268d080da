"""Step-response metrics of a closed-loop run, per step of a step reference (Figs. 9-10).

A step reference is anything with ``levels_m``, ``step_times_s`` and ``duration_s`` (a
:class:`~nfal.models.reference.Staircase`, or the steps found in a piecewise-constant reference): level
n + 1 from ``step_times_s[n]`` until the next step (the last until ``duration_s``), level 0 before the first.
For the step at t_s from level r0 to r1 (size D = r1 - r0), over its hold [t_s, next step) and on the
*true* clearance h (the sensor noise is not part of the response):

* rise time: first time h passes r0 + 0.9 D minus first time it passes r0 + 0.1 D [s];
* overshoot: max(0, max over the hold of (h - r1) sign(D)) / |D| x 100 [%];
* settling time: time after t_s from which |h - r1| stays within ``band`` |D| (2 %) [s];
* noise RMS: sqrt(mean((h - r1)^2)) over the last ``steady_fraction`` of the hold [m];
* IAE: integral of |r - h| dt over the hold [m s] (rectangle rule at the sampling instants).

A metric that is not reached within the hold (no 90 % crossing, never settling) is None.

A level is *reached* (:func:`level_reach`) when h came within ``REACHED_BAND`` |D| of it (10 %: the rise
time's upper band) or crossed it at some time during its hold; the first level's D is from the run's
first height.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from nfal.errors import InvalidParameterError

if TYPE_CHECKING:  # annotations only: the metrics need no plant (nor its compiled kernels)
    from .closed_loop import ClosedLoopRun

SETTLING_BAND = 0.02
STEADY_FRACTION = 0.25
REACHED_BAND = 0.1


@dataclasses.dataclass(frozen=True)
class StepMetrics:
    """Metrics of one step (SI; None where not reached)."""

    from_m: float
    to_m: float
    rise_time_s: float | None
    overshoot_percent: float
    settling_time_s: float | None
    noise_rms_m: float
    iae: float

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def _first_crossing(time: np.ndarray, progress: np.ndarray, level: float) -> float | None:
    """First time the (increasing-is-forward) ``progress`` reaches ``level``, linearly interpolated."""
    reached = np.flatnonzero(progress >= level)
    if reached.size == 0:
        return None
    i = reached[0]
    if i == 0:
        return float(time[0])
    fraction = (level - progress[i - 1]) / (progress[i] - progress[i - 1])
    return float(time[i - 1] + fraction * (time[i] - time[i - 1]))


def _holds(reference) -> list[tuple[float, float]]:
    """[start, end) [s] of every level of the step reference ``reference`` (the first from -inf)."""
    starts = [float(t) for t in reference.step_times_s]
    return list(zip([-np.inf, *starts], [*starts, float(reference.duration_s)]))


def _window(run: ClosedLoopRun, start: float, end: float) -> slice:
    """The samples with start <= t < end (to 1e-12 s), found by bisection of the (increasing) times: a run of
    10 minutes at 2 kHz has 1000 steps, and a mask over all 1.2 million samples for each took 30 s."""
    return slice(*np.searchsorted(run.time_s, (start - 1e-12, end - 1e-12), side="left"))


def step_metrics(run: ClosedLoopRun, reference, *, band: float = SETTLING_BAND,
                 steady_fraction: float = STEADY_FRACTION) -> list[StepMetrics]:
    """The metrics of every step of the step reference ``reference`` in ``run`` (see the module docstring)."""
    if not (0 < band < 1):
        raise InvalidParameterError("band", band, "a fraction in (0, 1)")
    if not (0 < steady_fraction <= 1):
        raise InvalidParameterError("steady_fraction", steady_fraction, "a fraction in (0, 1]")
    period = float(run.time_s[1] - run.time_s[0])
    results = []
    levels = reference.levels_m
    for n, (start, end) in enumerate(_holds(reference)[1:]):
        r0, r1 = levels[n], levels[n + 1]
        window = _window(run, start, end)
        t, h = run.time_s[window] - start, run.height_m[window]
        size = r1 - r0
        if size == 0:
            raise InvalidParameterError("levels_m", levels, "consecutive levels that differ")
        progress = (h - r0) / size  # 0 at the old level, 1 at the new one
        t10, t90 = _first_crossing(t, progress, 0.1), _first_crossing(t, progress, 0.9)
        rise = None if t10 is None or t90 is None else t90 - t10
        overshoot = max(0.0, float(np.max(progress)) - 1.0) * 100.0
        outside = np.flatnonzero(np.abs(progress - 1.0) > band)
        if outside.size == 0:
            settling = 0.0
        elif outside[-1] == t.size - 1:
            settling = None
        else:
            settling = float(t[outside[-1] + 1])
        steady = h[int(np.floor((1.0 - steady_fraction) * h.size)):]
        noise = float(np.sqrt(np.mean((steady - r1) ** 2)))
        iae = float(np.sum(np.abs(run.reference_m[window] - h)) * period)
        results.append(StepMetrics(float(r0), float(r1), rise, overshoot, settling, noise, iae))
    return results


@dataclasses.dataclass(frozen=True)
class LevelReach:
    """How near the height came to one level of a step reference during its hold (SI)."""

    level_m: float
    start_s: float   #: the hold [start_s, end_s)
    end_s: float
    band_m: float    #: REACHED_BAND times the step into the level
    lowest_m: float  #: the height's range over the hold
    highest_m: float

    @property
    def reached(self) -> bool:
        """Within the band of the level, or crossed it, at some time of the hold."""
        return self.lowest_m - self.band_m <= self.level_m <= self.highest_m + self.band_m


def level_reach(run: ClosedLoopRun, reference, *, band: float = REACHED_BAND) -> list[LevelReach]:
    """For every level of the step reference ``reference`` with samples in ``run``: how near the height came."""
    levels, reach = reference.levels_m, []
    for n, (start, end) in enumerate(_holds(reference)):
        h = run.height_m[_window(run, start, end)]
        if h.size:
            previous = levels[n - 1] if n else float(run.height_m[0])
            reach.append(LevelReach(float(levels[n]), max(start, float(run.time_s[0])), end,
                                    band * abs(levels[n] - previous), float(np.min(h)), float(np.max(h))))
    return reach


#: Noise RMS multiples within which a settling band is left by the noise alone: Gaussian noise leaves +-3 RMS once in
#: about 370 independent samples, and a hold has hundreds (0.6 s at 2 kHz, correlated over the 300 Hz colouring).
NOISE_BAND_RMS = 3.0


def noise_limits_settling(step: dict) -> bool:
    """Whether the judged height's noise alone leaves the settling band of a step (a :meth:`StepMetrics.to_dict` row):
    the band's half-width is within :data:`NOISE_BAND_RMS` noise RMS of the level, so the settling time is when the
    noise last left it, not the object's motion (`nfal run fig7_slow`, its 100 -> 60 um step: 0.8 um band, 0.32 um RMS,
    "settled" in 346 ms where the others took 45-58 ms)."""
    return NOISE_BAND_RMS * step["noise_rms_m"] >= SETTLING_BAND * abs(step["to_m"] - step["from_m"])


def total_iae(run: ClosedLoopRun, where: np.ndarray | None = None) -> float:
    """Integral of |r - h| dt over the whole run, or over the samples ``where`` selects [m s]."""
    error = np.abs(run.reference_m - run.height_m)
    return float(np.sum(error if where is None else error[where]) * (run.time_s[1] - run.time_s[0]))
