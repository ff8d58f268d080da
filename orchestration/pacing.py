"""Real-time pacing: communication step k is released at wall time t0 + k dt.

:meth:`RealTimePacer.wait` sleeps until the release time of step k (the last ``spin_s`` by busy
waiting, since ``time.sleep`` overshoots by tens of microseconds) and records the step's lateness:
the wall time it actually started minus its release time (its jitter). :meth:`RealTimePacer.done`
records when the step finished; a step that finishes after the release time of the next one is an
overrun. A late step is not skipped and the schedule is not shifted: later steps keep their release
times, so the run catches up when it can. :meth:`RealTimePacer.report` gives the counts and the
max / mean / p50 / p95 / p99 jitter for ``summary.json``, over every step, in bounded memory
(:class:`~nfal.realtime.LatencyStats`: a process that runs for hours keeps nothing per step).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys
import time
from collections.abc import Callable, Iterator

from nfal.errors import InvalidParameterError, RealtimePriorityError, require_positive
from nfal.realtime import LatencyStats, StealWatch

#: Overruns listed one by one in the report (all are counted).
FIRST_OVERRUNS = 10
#: The pacer samples the hypervisor's steal every this many steps (50 ms at 2 kHz; a read of /proc/stat: 31 us here,
#: ``python -m timeit -s 'from nfal.realtime import steal_s' 'steal_s()'``).
STEAL_EVERY = 100
_PR_SET_TIMERSLACK = 29
#: The interpreter's thread switch interval while paced [s] (Python's default is 5 ms).
SWITCH_INTERVAL_S = 5e-5
#: Real-time priorities SCHED_FIFO takes on Linux (``chrt -m`` lists them).
RT_PRIORITIES = range(1, 100)


def fine_timer_slack() -> None:
    """Linux: give the calling thread a 1 ns timer slack (default 50 us), so that ``time.sleep`` wakes
    closer to its deadline (measured here: median oversleep 96 -> 34 us for 0.2 ms sleeps) and the
    busy wait before a release can be short. Elsewhere, or if prctl is unavailable, nothing happens."""
    if not sys.platform.startswith("linux"):
        return
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_TIMERSLACK, 1, 0, 0, 0)
    except (OSError, AttributeError):
        pass


@contextlib.contextmanager
def prompt_thread_switching(interval_s: float = SWITCH_INTERVAL_S) -> Iterator[None]:
    """Shorten the interpreter's thread switch interval for a paced loop.

    A thread that wants the GIL waits up to the switch interval for the thread holding it. An FMU's helper
    thread (the HardwareProxy's serial reader) would otherwise wait up to 5 ms behind the master's busy
    wait, and the master up to 5 ms behind it: both far longer than a 0.5 ms step.
    """
    previous = sys.getswitchinterval()
    sys.setswitchinterval(interval_s)
    try:
        yield
    finally:
        sys.setswitchinterval(previous)


@contextlib.contextmanager
def realtime_priority(priority: int | None) -> Iterator[None]:
    """Run the calling thread (and threads it starts) under Linux's SCHED_FIFO at ``priority`` (1-99), then
    restore its policy; None: leave the scheduling alone.

    A SCHED_FIFO thread is not preempted by ordinary processes, so a paced loop's release is not delayed by
    whatever else the machine runs (measured in docs/benchmark-notes.md, "Hardware in the loop"). The kernel's
    real-time throttling (``/proc/sys/kernel/sched_rt_runtime_us``, 95 % of a CPU by default) keeps a
    runaway loop from freezing the machine. Raises :class:`RealtimePriorityError` if the process may not
    have it (it needs root, CAP_SYS_NICE or an ``rtprio`` limit), before anything runs.
    """
    if priority is None:
        yield
        return
    if isinstance(priority, bool) or not isinstance(priority, int) or priority not in RT_PRIORITIES:
        raise InvalidParameterError("rt_priority", priority, "a whole number from 1 to 99, or None")
    if not hasattr(os, "sched_setscheduler"):
        raise RealtimePriorityError(f"rt_priority = {priority}: this platform has no SCHED_FIFO (Linux has)")
    policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError:
        raise RealtimePriorityError(
            f"rt_priority = {priority}: the system refused SCHED_FIFO to this process; run as root, give python "
            f"CAP_SYS_NICE (setcap cap_sys_nice+ep), or allow your user an rtprio in "
            f"/etc/security/limits.conf - or leave the priority out") from None
    try:
        yield
    finally:
        os.sched_setscheduler(0, policy, param)


def require_realtime_priority(priority: int | None) -> None:
    """Raise :class:`RealtimePriorityError` now if this process may not run at ``priority`` (tried, then undone),
    so that a command refuses before it builds or opens anything; None: nothing to check."""
    with realtime_priority(priority):
        pass


def realtime_priority_refusal(priority: int) -> str | None:
    """Why this process may not run at ``priority`` under SCHED_FIFO, or None if it may (tried, then undone)."""
    try:
        require_realtime_priority(priority)
    except RealtimePriorityError as exc:
        return str(exc)
    return None


class ReleaseStats:
    """What a paced loop's steps did, in bounded memory: each release's lateness, each step's duration, the overruns
    (steps that ended after the next release: all counted, the first FIRST_OVERRUNS listed) [s], and what the
    hypervisor took meanwhile (``steal``, sampled by the loop's owner). The pacer keeps them for its steps, and
    :mod:`nfal.apps.compiled_run` for the compiled loop's, so both report alike."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.lateness, self.durations = LatencyStats(), LatencyStats()
        self.overruns: list[tuple[int, float]] = []
        self.overrun_count, self.overrun_max = 0, 0.0
        self.steal = StealWatch()

    def released(self, lateness_s: float) -> None:
        """A step started ``lateness_s`` after its release time."""
        self.lateness.add(lateness_s)

    def finished(self, k: int, duration_s: float, excess_s: float) -> bool:
        """Step ``k`` took ``duration_s`` and ended ``excess_s`` after the next release (> 0: an overrun, True)."""
        self.durations.add(duration_s)
        if excess_s <= 0:
            return False
        self.overrun_count += 1
        self.overrun_max = max(self.overrun_max, excess_s)
        if len(self.overruns) < FIRST_OVERRUNS:
            self.overruns.append((k, excess_s))
        return True

    def report(self) -> dict:
        """``summary.json``'s ``realtime`` counts and statistics [s]."""
        lateness, durations = self.lateness, self.durations
        return {
            "period_s": self.period_s,
            "steps": lateness.count,
            "overruns": self.overrun_count,
            "overrun_max_s": self.overrun_max,
            "first_overruns": [{"step": k, "excess_s": e} for k, e in self.overruns],
            "jitter_max_s": lateness.maximum,
            "jitter_mean_s": lateness.total / lateness.count if lateness.count else 0.0,
            **{f"jitter_p{q}_s": lateness.percentile(q) for q in (50, 95, 99)},
            "step_duration_max_s": durations.maximum,
            "step_duration_mean_s": durations.total / durations.count if durations.count else 0.0,
            "steal": self.steal.report(),
        }


class RealTimePacer:
    """Release fixed steps on the wall clock and measure how well that went.

    Parameters
    ----------
    step_size : float
        Communication step [s] of simulated time, released every ``step_size / speed`` s of wall time.
    speed : float
        Simulated seconds per wall second (1: real time).
    spin_s : float
        How long before a release to stop sleeping and busy-wait [s] (0: sleep only). Default 100 us: with
        the 1 ns timer slack, sleeps overshoot by 34 us median, 79 us p99 here; a longer busy wait costs a
        2-core machine the CPU a second real-time process needs (docs/benchmark-notes.md, "Hardware in the loop").
    clock, sleep : callables
        Injected for tests; default ``time.perf_counter`` and ``time.sleep``.
    resync_after_s : float, optional
        A step released later than this is taken as the new origin: later releases shift by its lateness
        instead of following in a burst to catch up (counted as resyncs, and the time given up is summed).
        Default: never (the schedule is kept). For a process that plays hardware, whose clock cannot run
        faster than real time to make up for a stall.
    min_sleep_s : float
        The least this thread sleeps before each release [s], even when it is late (0: none). For a thread at a
        real-time priority: one that is late runs its steps back to back and, without it, holds its CPU for as long
        as it stays late, while the kernel work queued there (a pty's, for the process on the other end) waits.
    """

    def __init__(self, step_size: float, *, speed: float = 1.0, spin_s: float = 1e-4,
                 clock: Callable[[], float] = time.perf_counter, sleep: Callable[[float], None] = time.sleep,
                 resync_after_s: float | None = None, min_sleep_s: float = 0.0) -> None:
        self.period = require_positive("step_size", step_size) / require_positive("speed", speed)
        if not 0.0 <= spin_s < 1.0:
            raise InvalidParameterError("spin_s", spin_s, "in [0, 1) s")
        self.spin_s, self.clock, self.sleep = float(spin_s), clock, sleep
        self.start_time: float | None = None
        self.stats = ReleaseStats(self.period)
        if resync_after_s is not None and not resync_after_s > 0:
            raise InvalidParameterError("resync_after_s", resync_after_s, "> 0 s, or None")
        self.resync_after_s = resync_after_s
        if not 0.0 <= min_sleep_s < self.period:
            raise InvalidParameterError("min_sleep_s", min_sleep_s, f"in [0, {self.period:g}) s (the step's period)")
        self.min_sleep_s = float(min_sleep_s)
        self.resyncs = 0
        self.time_given_up = 0.0
        self._started_at = 0.0

    def start(self) -> None:
        """Make now the wall time of step 0's release (t0) (and sharpen this thread's sleeps:
        :func:`fine_timer_slack`)."""
        fine_timer_slack()
        self.start_time = self.clock()

    def release_time(self, k: int) -> float:
        if self.start_time is None:
            self.start()
        return self.start_time + k * self.period

    def wait(self, k: int) -> float:
        """Block until step ``k``'s release time; return (and record) its lateness [s] (>= 0)."""
        deadline = self.release_time(k)
        pause = max(deadline - self.clock() - self.spin_s, self.min_sleep_s)
        if pause > 0:
            self.sleep(pause)
        now = self.clock()
        while now < deadline:
            now = self.clock()
        self._started_at = now
        lateness = now - deadline
        self.stats.released(lateness)
        if self.resync_after_s is not None and lateness > self.resync_after_s:
            self.start_time += lateness
            self.resyncs += 1
            self.time_given_up += lateness
        return lateness

    def restart(self, k: int) -> None:
        """Make now step ``k``'s release time (after a stretch of steps not released by this pacer)."""
        self.start_time = self.clock() - k * self.period

    def sleep_until(self, k: int) -> None:
        """Block until step ``k``'s release time without recording it (e.g. the end of the run)."""
        remaining = self.release_time(k) - self.clock()
        if remaining > 0:
            self.sleep(remaining)

    def done(self, k: int) -> bool:
        """Record that step ``k`` finished; True if it overran (finished after step k + 1's release)."""
        now = self.clock()
        if k % STEAL_EVERY == 0:
            self.stats.steal.sample()
        return self.stats.finished(k, now - self._started_at, now - self.release_time(k + 1))

    def report(self) -> dict:
        """Counts and statistics of the steps so far [s] (see the module docstring)."""
        stats = self.stats.report()
        if self.resync_after_s is not None:
            stats.update(resyncs=self.resyncs, time_given_up_s=self.time_given_up)
        if self.start_time is not None:
            stats["wall_time_s"] = self.clock() - self.start_time + self.time_given_up
        return stats
