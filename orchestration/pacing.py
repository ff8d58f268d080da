"""Real-time pacing: communication step k is released at wall time t0 + k dt.

:meth:`RealTimePacer.wait` sleeps until the release time of step k (the last ``spin_s`` by busy
waiting, since ``time.sleep`` overshoots by tens of microseconds) and records the step's lateness:
the wall time it actually started minus its release time (its jitter). :meth:`RealTimePacer.done`
records when the step finished; a step that finishes after the release time of the next one is an
overrun. A late step is not skipped and the schedule is not shifted: later steps keep their release
times, so the run catches up when it can. :meth:`RealTimePacer.report` gives the counts and the
max / mean / 95th-percentile jitter for ``summary.json``.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from nfal.models.errors import InvalidParameterError, require_positive


class RealTimePacer:
    """Release fixed steps on the wall clock and measure how well that went.

    Parameters
    ----------
    step_size : float
        Communication step [s] of simulated time, released every ``step_size / speed`` s of wall time.
    speed : float
        Simulated seconds per wall second (1: real time).
    spin_s : float
        How long before a release to stop sleeping and busy-wait [s] (0: sleep only).
    clock, sleep : callables
        Injected for tests; default ``time.perf_counter`` and ``time.sleep``.
    """

    def __init__(self, step_size: float, *, speed: float = 1.0, spin_s: float = 2e-4,
                 clock: Callable[[], float] = time.perf_counter, sleep: Callable[[float], None] = time.sleep) -> None:
        self.period = require_positive("step_size", step_size) / require_positive("speed", speed)
        if not 0.0 <= spin_s < 1.0:
            raise InvalidParameterError("spin_s", spin_s, "in [0, 1) s")
        self.spin_s, self.clock, self.sleep = float(spin_s), clock, sleep
        self.start_time: float | None = None
        self.lateness: list[float] = []
        self.durations: list[float] = []
        self.overruns: list[tuple[int, float]] = []
        self._started_at = 0.0

    def start(self) -> None:
        """Make now the wall time of step 0's release (t0)."""
        self.start_time = self.clock()

    def release_time(self, k: int) -> float:
        if self.start_time is None:
            self.start()
        return self.start_time + k * self.period

    def wait(self, k: int) -> float:
        """Block until step ``k``'s release time; return (and record) its lateness [s] (>= 0)."""
        deadline = self.release_time(k)
        remaining = deadline - self.clock()
        if remaining > self.spin_s:
            self.sleep(remaining - self.spin_s)
        now = self.clock()
        while now < deadline:
            now = self.clock()
        self._started_at = now
        lateness = now - deadline
        self.lateness.append(lateness)
        return lateness

    def sleep_until(self, k: int) -> None:
        """Block until step ``k``'s release time without recording it (e.g. the end of the run)."""
        remaining = self.release_time(k) - self.clock()
        if remaining > 0:
            self.sleep(remaining)

    def done(self, k: int) -> bool:
        """Record that step ``k`` finished; True if it overran (finished after step k + 1's release)."""
        now = self.clock()
        self.durations.append(now - self._started_at)
        excess = now - self.release_time(k + 1)
        if excess > 0:
            self.overruns.append((k, excess))
            return True
        return False

    def report(self) -> dict:
        """Counts and statistics of the steps so far [s] (see the module docstring)."""
        lateness = np.asarray(self.lateness, dtype=float)
        durations = np.asarray(self.durations, dtype=float)
        stats = {
            "period_s": self.period,
            "steps": int(lateness.size),
            "overruns": len(self.overruns),
            "overrun_max_s": max((e for _, e in self.overruns), default=0.0),
            "first_overruns": [{"step": k, "excess_s": e} for k, e in self.overruns[:10]],
            "jitter_max_s": float(lateness.max()) if lateness.size else 0.0,
            "jitter_mean_s": float(lateness.mean()) if lateness.size else 0.0,
            "jitter_p95_s": float(np.percentile(lateness, 95)) if lateness.size else 0.0,
            "step_duration_max_s": float(durations.max()) if durations.size else 0.0,
            "step_duration_mean_s": float(durations.mean()) if durations.size else 0.0,
        }
        if self.start_time is not None:
            stats["wall_time_s"] = self.clock() - self.start_time
        return stats
