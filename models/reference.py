"""The loop's height reference: the paper's staircase (:class:`Staircase`) and any step sequence, change times and
levels held between changes (SI). Plain numbers and numpy only, so that the ReferenceGenerator FMU imports nothing
heavier.

:class:`StepSequence` is the reference of the Fig. 7 loop in plain numbers, so that the ReferenceGenerator
FMU (``fmus/reference_generator.py``) and the master's ``--reference`` (``nfal.orchestration.signals``)
give the same value at every communication point. It is built from

* the paper's staircase or any other (:meth:`StepSequence.from_staircase`, a
  :class:`Staircase`: levels [m], a lead and a hold [s]);
* explicit change times and levels (:meth:`StepSequence.from_text`, ``"0, 0.1, 0.7"`` and
  ``"60e-6, 100e-6, 140e-6"``);
* a table of ``time_s,reference_m`` rows (:meth:`StepSequence.from_table`), rows separated by newlines,
  ``;`` or white space (an SSV attribute turns newlines into spaces), an optional header line and ``#``
  comment lines.

At time t the value is the level of the last change at or before t; before the first change, the first
level. A time within 1e-12 s (relative 1e-12) before a change counts as at the change, as in
``nfal.orchestration.signals``, so that a communication point computed as ``t + dt`` and one computed as
``k * dt`` agree.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
import re

import numpy as np

from nfal.errors import DataFormatError, InvalidParameterError, require_positive

from .table2 import STAIRCASE_LEVELS_M

#: Time tolerance [s] of a change (absolute and relative), see the module docstring.
TIME_TOLERANCE = 1e-12
#: What separates the rows of a table given as text.
_ROW_SEPARATOR = re.compile(r"[;\s]+")


@dataclasses.dataclass(frozen=True)
class Staircase:
    """A piecewise-constant reference: ``levels_m`` [m], the first held ``lead_s`` [s], the others ``hold_s``."""

    levels_m: tuple[float, ...] = STAIRCASE_LEVELS_M
    hold_s: float = 0.6
    lead_s: float = 0.1

    def __post_init__(self) -> None:
        levels = tuple(require_positive("levels_m", v) for v in self.levels_m)
        if len(levels) < 2:
            raise InvalidParameterError("levels_m", self.levels_m, "at least two levels")
        object.__setattr__(self, "levels_m", levels)
        require_positive("hold_s", self.hold_s)
        require_positive("lead_s", self.lead_s)

    @property
    def duration_s(self) -> float:
        return self.lead_s + self.hold_s * (len(self.levels_m) - 1)

    @property
    def step_times_s(self) -> np.ndarray:
        """Times [s] of the steps (one fewer than the levels)."""
        return self.lead_s + self.hold_s * np.arange(len(self.levels_m) - 1)

    def completed_by(self, stop_time_s: float | None) -> "Staircase | None":
        """The staircase cut to the steps whose holds end by ``stop_time_s`` [s] (None: no step does)."""
        if stop_time_s is None or stop_time_s >= self.duration_s - 1e-9:
            return self
        levels = int((stop_time_s - self.lead_s) / self.hold_s + 1e-9) + 1
        if levels < 2:
            return None
        return Staircase(self.levels_m[:levels], hold_s=self.hold_s, lead_s=self.lead_s)

    def samples(self, sample_rate_hz: float) -> int:
        """Number of controller samples in the run at ``sample_rate_hz`` [Hz]."""
        return int(round(self.duration_s * require_positive("sample_rate_hz", sample_rate_hz)))

    def __call__(self, time_s) -> np.ndarray:
        """The reference [m] at ``time_s`` [s]."""
        index = np.searchsorted(self.step_times_s, np.asarray(time_s, dtype=float), side="right")
        return np.asarray(self.levels_m)[index]


@dataclasses.dataclass(frozen=True)
class StepSequence:
    """A zero-order-hold reference: ``levels_m[i]`` [m] from ``times_s[i]`` [s] until the next change.

    ``duration_s`` is the sequence's natural length [s] (a staircase's last hold ends there; else the
    last change time).
    """

    times_s: tuple[float, ...]
    levels_m: tuple[float, ...]
    duration_s: float | None = None

    def __post_init__(self) -> None:
        times = tuple(float(t) for t in self.times_s)
        levels = tuple(float(v) for v in self.levels_m)
        if not times or len(times) != len(levels):
            raise InvalidParameterError("step sequence", f"{len(times)} times, {len(levels)} levels",
                                        "as many change times as levels, at least one")
        for i, (t, level) in enumerate(zip(times, levels)):
            if not math.isfinite(t):
                raise InvalidParameterError(f"change time {i + 1}", t, "a finite time [s]")
            if not (math.isfinite(level) and level > 0):
                raise InvalidParameterError(f"level {i + 1}", level, "a finite height > 0 [m]")
        for i in range(1, len(times)):
            if times[i] <= times[i - 1]:
                raise InvalidParameterError(f"change time {i + 1}", times[i],
                                            f"later than change {i} at {times[i - 1]!r} s (times increase strictly)")
        duration = times[-1] if self.duration_s is None else float(self.duration_s)
        if not (math.isfinite(duration) and duration >= times[-1]):
            raise InvalidParameterError("duration_s", self.duration_s, f"finite and >= the last change {times[-1]!r} s")
        object.__setattr__(self, "times_s", times)
        object.__setattr__(self, "levels_m", levels)
        object.__setattr__(self, "duration_s", duration)

    def __call__(self, time_s: float) -> float:
        """The reference [m] at ``time_s`` [s]."""
        t = float(time_s)
        index = bisect.bisect_right(self.times_s, t + TIME_TOLERANCE * (1.0 + abs(t)))
        return self.levels_m[max(index - 1, 0)]

    @classmethod
    def from_staircase(cls, staircase: Staircase) -> "StepSequence":
        """The staircase's levels, changing at its step times (the first from 0 s)."""
        return cls((0.0, *(float(t) for t in staircase.step_times_s)), staircase.levels_m, staircase.duration_s)

    @classmethod
    def from_text(cls, times: str, levels: str) -> "StepSequence":
        """Change times [s] and levels [m], each a comma- or space-separated list of numbers."""
        return cls(numbers("times", times), numbers("levels", levels))

    @classmethod
    def from_table(cls, text: str, *, name: str = "table") -> "StepSequence":
        """Rows of ``time_s,reference_m`` (see the module docstring); a first row that is not numbers is a header."""
        rows = [row for line in text.splitlines() if not line.strip().startswith("#")
                for row in _ROW_SEPARATOR.split(re.sub(r"\s*,\s*", ",", line.strip())) if row]
        times, levels = [], []
        for i, row in enumerate(rows):
            fields = [f.strip() for f in row.split(",")]
            try:
                values = [float(f) for f in fields]
            except ValueError:
                if i == 0:  # a header line such as time_s,reference_m
                    continue
                raise DataFormatError(f"{name}: row {i + 1} {row!r} is not two numbers time_s,reference_m") from None
            if len(values) != 2:
                raise DataFormatError(f"{name}: row {i + 1} {row!r} has {len(values)} fields, "
                                      "expected time_s,reference_m")
            times.append(values[0])
            levels.append(values[1])
        if not times:
            raise DataFormatError(f"{name}: no rows of time_s,reference_m")
        return cls(tuple(times), tuple(levels))


def staircase_of(sequence: StepSequence) -> Staircase | None:
    """The :class:`Staircase` that ``sequence`` is (first change at 0 s, equal holds after the lead, at least
    two levels, the last hold complete), else None (for the step metrics, which need a staircase)."""
    times = sequence.times_s
    if len(times) < 2 or times[0] != 0.0:
        return None
    lead = times[1]
    hold = (sequence.duration_s - lead) / (len(times) - 1)
    if not (lead > 0 and hold > 0):
        return None
    staircase = Staircase(sequence.levels_m, hold_s=hold, lead_s=lead)
    if any(abs(a - b) > 1e-9 for a, b in zip(staircase.step_times_s, times[1:])):
        return None
    return staircase


def numbers(name: str, text: str) -> tuple[float, ...]:
    """The numbers of ``text``, separated by commas, semicolons or spaces (``name`` for the error)."""
    fields = [f for f in re.split(r"[,;\s]+", text.strip()) if f]
    try:
        return tuple(float(f) for f in fields)
    except ValueError:
        raise InvalidParameterError(name, text, "numbers separated by commas or spaces") from None
