"""Reference signals for external inputs: built-in step sequences and a CSV of (time, value).

Every signal here is a :class:`PiecewiseConstant` (zero-order hold: at time t the value of the
last change at or before t), callable as ``signal(t) -> float`` in SI. A step sequence of an
application (an object with ``levels_m``, ``step_times_s`` and ``duration_s``, such as the Fig. 7
loop's :class:`nfal.models.reference.Staircase`) becomes one with the same values, so that the
co-simulation and the pure-Python loop see the same reference. The other way, :func:`steps_of` finds the steps
of a piecewise-constant signal (a CSV reference), so that it gets the step metrics a staircase gets.

A time within 1e-12 s (relative 1e-12) before a change counts as at the change, so that a
communication point computed as ``k * dt`` and a change at ``0.1`` agree.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from nfal.csvdata import read_numeric_csv
from nfal.errors import DataFormatError, SignalError, shown

#: Time tolerance [s] of a change (absolute and relative), see the module docstring.
TIME_TOLERANCE = 1e-12
TIME_COLUMNS = ("time_s", "time", "t", "time [s]")
#: The shortest hold [s] of a level for a signal to count as steps (:func:`steps_of`): one that changes faster
#: (a ramp or a sine sampled into rows) is a curve, not levels a loop is meant to settle on.
MIN_STEP_HOLD_S = 0.05


class PiecewiseConstant:
    """A zero-order-hold signal: ``values[i]`` from ``times[i]`` until ``times[i + 1]``.

    Before ``times[0]`` the value is ``values[0]``; after the last time, the last value.

    Parameters
    ----------
    times : sequence of float
        Change times [s], strictly increasing.
    values : sequence of float
        One value per time (SI).
    name : str
        For messages and the run summary.
    duration_s : float, optional
        A natural stop time [s] for runs driven by this signal (default: the last change time).
    """

    def __init__(self, times: Sequence[float], values: Sequence[float], *, name: str = "signal",
                 duration_s: float | None = None) -> None:
        times, values = [float(t) for t in times], [float(v) for v in values]
        if not times or len(times) != len(values):
            raise SignalError(f"{name}: needs as many times as values, at least one ({len(times)} times, "
                              f"{len(values)} values)")
        for i, (t, v) in enumerate(zip(times, values)):
            if not (math.isfinite(t) and math.isfinite(v)):
                raise SignalError(f"{name}: row {i + 1} is not finite (time {t}, value {v})")
        for i in range(1, len(times)):
            if times[i] <= times[i - 1]:
                raise SignalError(f"{name}: time must increase strictly, but row {i + 1} has t = {times[i]!r} s after "
                                  f"t = {times[i - 1]!r} s in row {i}")
        self.times, self.values, self.name = tuple(times), tuple(values), name
        self.duration_s = times[-1] if duration_s is None else float(duration_s)

    def __call__(self, time_s: float) -> float:
        t = float(time_s)
        index = bisect.bisect_right(self.times, t + TIME_TOLERANCE * (1.0 + abs(t)))
        return self.values[max(index - 1, 0)]

    def __repr__(self) -> str:
        return f"PiecewiseConstant({self.name!r}, {len(self.times)} levels)"

    def describe(self, max_levels: int = 50) -> dict:
        """A JSON-ready description, for the run summary (times and values when there are few)."""
        description = {"name": self.name, "levels": len(self.times), "duration_s": self.duration_s}
        if len(self.times) <= max_levels:
            description.update(times_s=list(self.times), values=list(self.values))
        return description


def is_step_sequence(source: object) -> bool:
    """Whether ``source`` is a step sequence: it has ``levels_m``, ``step_times_s`` and ``duration_s``."""
    return all(hasattr(source, name) for name in ("levels_m", "step_times_s", "duration_s"))


def from_staircase(steps: object, *, name: str = "staircase") -> PiecewiseConstant:
    """A step sequence (see :func:`is_step_sequence`) as a :class:`PiecewiseConstant` (same values)."""
    times = [0.0, *map(float, steps.step_times_s)]
    return PiecewiseConstant(times, steps.levels_m, name=name, duration_s=steps.duration_s)


@dataclasses.dataclass(frozen=True)
class Steps:
    """A step sequence (:func:`is_step_sequence`): ``levels_m[0]`` until ``step_times_s[0]``, then ``levels_m[n + 1]``
    from ``step_times_s[n]`` until the next step, the last until ``duration_s`` [s]."""

    levels_m: tuple[float, ...]
    step_times_s: tuple[float, ...]
    duration_s: float


def steps_of(signal: PiecewiseConstant, start_s: float, end_s: float, *,
             min_hold_s: float = MIN_STEP_HOLD_S) -> tuple[Steps | None, str | None]:
    """The steps of ``signal`` in a run from ``start_s`` to ``end_s`` [s], or None and why there are none.

    Rows that repeat a value are one level. A step counts when its hold is complete by ``end_s`` (it ends at
    the next change, or the signal changes no more; such a last hold shorter than ``min_hold_s`` is cut off
    by the run's end and left out). A signal with a shorter hold is not steps (a sampled ramp or sine).
    """
    times, values = signal.times, signal.values
    changes = [times[i] for i in range(1, len(times)) if values[i] != values[i - 1]]
    nexts = [*changes[1:], math.inf]  # the end of each change's level
    inside = [(t, end) for t, end in zip(changes, nexts) if start_s < t < end_s]
    if not inside:
        return None, f"the reference has no step between {start_s:g} s and {end_s:g} s"
    holds = [(t, min(end, end_s)) for t, end in inside
             if end <= end_s + TIME_TOLERANCE or (end == math.inf and end_s - t >= min_hold_s)]
    if not holds:
        return None, f"no step of the reference completes its hold by {end_s:g} s"
    shortest = min(end - start for start, end in holds)
    if shortest < min_hold_s:
        return None, (f"the reference is not a sequence of steps: it changes {len(inside)} times, holding a level "
                      f"as little as {shortest * 1e3:.3g} ms (steps are held {min_hold_s * 1e3:g} ms or more)")
    step_times = tuple(start for start, _ in holds)
    levels = (signal(start_s), *(signal(t) for t in step_times))
    return Steps(levels, step_times, holds[-1][1]), None


def staircase(levels_m: Sequence[float], hold_s: float, lead_s: float) -> PiecewiseConstant:
    """Steps through ``levels_m`` [m]: the first held ``lead_s``, the others ``hold_s`` [s]."""
    if len(levels_m) < 2 or not (hold_s > 0 and lead_s > 0):
        raise SignalError(f"staircase: levels {shown(list(levels_m))}, hold {shown(hold_s)} s, lead {shown(lead_s)} s: "
                          "expected two or more levels and a hold and lead > 0")
    times = [0.0, *map(float, lead_s + hold_s * np.arange(len(levels_m) - 1))]
    return PiecewiseConstant(times, levels_m, name="staircase", duration_s=lead_s + hold_s * (len(levels_m) - 1))


def step(initial: float, final: float, at_s: float) -> PiecewiseConstant:
    """``initial`` until ``at_s`` [s], then ``final``."""
    if not at_s > 0:
        raise SignalError(f"step: at_s = {at_s!r} must be > 0")
    return PiecewiseConstant([0.0, at_s], [initial, final], name=f"step {initial:g} -> {final:g} at {at_s:g} s")


def constant(value: float) -> PiecewiseConstant:
    """``value`` at all times."""
    return PiecewiseConstant([0.0], [value], name=f"constant {value:g}", duration_s=0.0)


def csv_signal(path: str | os.PathLike, *, column: str | None = None) -> PiecewiseConstant:
    """A signal from a CSV of (time_s, value) rows, held between rows.

    The file may have a header line and ``#`` comment lines. With a header, the time column is the
    one named ``time_s`` (or ``time``, ``t``), else the first; the value column is ``column`` or the
    other one (there must then be exactly two).

    Raises
    ------
    SignalError
        Unreadable, not numeric, not finite, no rows, or times not strictly increasing (names the row).
    """
    path = Path(path)
    try:
        names, table = read_numeric_csv(path)
    except DataFormatError as exc:
        raise SignalError(str(exc)) from None
    time_index = next((names.index(n) for n in TIME_COLUMNS if n in names), 0)
    if column is not None:
        if column.lower() not in names:
            raise SignalError(f"{path}: no column {column!r} (columns: {', '.join(names)})")
        value_index = names.index(column.lower())
    else:
        others = [i for i in range(len(names)) if i != time_index]
        if len(others) != 1:
            raise SignalError(f"{path}: {len(names)} columns ({', '.join(names)}); expected time and one value, "
                              "or say which column")
        value_index = others[0]
    return PiecewiseConstant(table[:, time_index], table[:, value_index], name=path.name)


def signal_from_spec(spec: str) -> PiecewiseConstant:
    """A signal from a short text, for command lines.

    ``step:INITIAL,FINAL,AT``, ``constant:VALUE``, or the path of a CSV file (see :func:`csv_signal`).
    """
    kind, _, rest = spec.partition(":")
    try:
        if kind == "step":
            initial, final, at = (float(v) for v in rest.split(","))
            return step(initial, final, at)
        if kind == "constant":
            return constant(float(rest))
    except ValueError:
        raise SignalError(f"signal {spec!r}: expected step:INITIAL,FINAL,AT, constant:VALUE or a CSV file") from None
    if Path(spec).is_file():
        return csv_signal(spec)
    raise SignalError(f"signal {spec!r}: not a built-in signal (step:..., constant:...) nor an existing CSV file")


def as_signal(source: object, *, name: str = "input") -> Callable[[float], float]:
    """Anything a caller may give as an external input, as ``f(t) -> float``.

    A number is a constant; a step sequence (:func:`is_step_sequence`) becomes a
    :class:`PiecewiseConstant` (same values, faster); any other callable of time is wrapped so
    that its result is a float.
    """
    if isinstance(source, PiecewiseConstant):
        return source
    if is_step_sequence(source):
        return from_staircase(source)
    if isinstance(source, (int, float)) and not isinstance(source, bool):
        return constant(float(source))
    if callable(source):
        def call(time_s: float, _f=source) -> float:
            return float(_f(time_s))
        call.__name__ = getattr(source, "__name__", type(source).__name__)
        return call
    raise SignalError(f"{name}: {source!r} is neither a number nor a function of time")
