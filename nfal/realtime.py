"""The real-time discipline of every loop that meets the rig at 2 kHz (docs/hil.md, "Real time that holds").

A drive the rig holds for more than a few milliseconds at the wrong moment costs the levitated object overshoot, and a
rig's watchdog stops the run after 100 ms; a loop written in Python must not pause that long.
The pauses that grow with a run are the cyclic garbage collector's: a full collection walks every object the
process holds, so a loop that keeps a Python object per sample stalls longer the longer it runs. Hence:

* :func:`realtime_section`: on entry everything built so far is frozen (:func:`gc.freeze`: never scanned again; any
  garbage among it is collected after the section) and the automatic collector is switched off; the loop calls
  :meth:`SlackCollector.safe_point` where it has slack (right after a DRIVE left), which collects the young
  generations only, when they have filled (a bounded cost: they hold what the last few hundred samples made).
  The process's pages are locked in memory where the system allows it (:func:`lock_memory`). On exit the
  collector is restored.
* :class:`StealWatch`: what the machine's hypervisor took from its vCPUs while a loop ran (over the run, its worst
  second, the second before the end): a stall in a second of heavy steal was the machine's, not the loop's.
* :class:`LatencyStats`: bounded-memory statistics of a stream of durations (gaps between DRIVE commands,
  lateness of steps, collection pauses): exact count, mean and max, percentiles from a logarithmic histogram
  (:data:`BINS_PER_DECADE` bins a decade: within 2.3 % of the exact value), O(1) per value and nothing kept per value.

The loops keep nothing per sample as a Python object either: samples go to preallocated arrays, and to disk
through a :class:`BackgroundWriter`, whose thread waits for the disk (a writeback stall of 50-200 ms is common
when another program writes a lot) so that the loop never does. Inside a section the interpreter switches
threads every :data:`SWITCH_INTERVAL_S`, so that thread never holds the loop up for long.
"""

from __future__ import annotations

import collections
import contextlib
import ctypes
import dataclasses
import gc
import math
import os
import queue
import resource
import sys
import threading
import time
from collections.abc import Iterator
from typing import TextIO

#: Histogram resolution of :class:`LatencyStats` (a bin is 10 ** (1 / 100) = 2.3 % wide).
BINS_PER_DECADE = 100
#: The histogram's range [s]: shorter values count in the first bin, longer ones in the last.
SMALLEST_S, LONGEST_S = 1e-7, 1e3
#: Young objects (allocations minus deallocations) at which a safe point collects generation 0 (CPython's own
#: threshold is 700; a little more per collection costs little at 2 kHz).
YOUNG_THRESHOLD = 2000
#: Generation-0 collections after which a safe point collects generation 1 too (CPython's: 10).
MIDDLE_THRESHOLD = 10
#: The interpreter's thread switch interval inside a section [s] (Python's default is 5 ms: a helper thread could hold
#: the loop up that long).
SWITCH_INTERVAL_S = 5e-5
_MCL_CURRENT, _MCL_ONFAULT = 1, 4


class LatencyStats:
    """Count, mean, max and percentiles of durations [s] in bounded memory (see the module docstring)."""

    __slots__ = ("count", "total", "maximum", "_bins")

    def __init__(self) -> None:
        self.count, self.total, self.maximum = 0, 0.0, 0.0
        self._bins = [0] * (round(math.log10(LONGEST_S / SMALLEST_S) * BINS_PER_DECADE) + 1)

    def add(self, value: float) -> None:
        """Count one duration [s] (about 0.3 us)."""
        self.count += 1
        self.total += value
        if value > self.maximum:
            self.maximum = value
        index = int(math.log10(value / SMALLEST_S) * BINS_PER_DECADE) if value > SMALLEST_S else 0
        self._bins[min(index, len(self._bins) - 1)] += 1

    def percentile(self, q: float) -> float:
        """The ``q``-th percentile [s] (0-100): the geometric middle of its bin, at most the maximum (the maximum
        itself beyond LONGEST_S); 0 if empty."""
        if not self.count:
            return 0.0
        rank, seen, last = q / 100 * self.count, 0, len(self._bins) - 1
        for index, n in enumerate(self._bins[:last]):
            seen += n
            if n and seen >= rank:
                return min(SMALLEST_S * 10 ** ((index + 0.5) / BINS_PER_DECADE), self.maximum)
        return self.maximum  # in the last bin, open above

    def report(self) -> dict:
        """``{"count", "mean_s", "p50_s", "p99_s", "max_s"}``."""
        return {"count": self.count, "mean_s": self.total / self.count if self.count else 0.0,
                "p50_s": self.percentile(50), "p99_s": self.percentile(99), "max_s": self.maximum}


class GapStats(LatencyStats):
    """:class:`LatencyStats` of the gaps between successive events: :meth:`mark` each event with its time [s]."""

    __slots__ = ("_last",)

    def __init__(self) -> None:
        super().__init__()
        self._last: float | None = None

    def mark(self, now: float) -> None:
        if self._last is not None:
            self.add(now - self._last)
        self._last = now


@dataclasses.dataclass
class SlackCollector:
    """The collector of a :func:`realtime_section`: :meth:`safe_point` collects the young generations when due."""

    pauses: LatencyStats = dataclasses.field(default_factory=LatencyStats)
    memory_locked: bool = False
    memory_lock_note: str = ""

    def safe_point(self) -> None:
        """Collect generation 0 if it has filled (and generation 1 every MIDDLE_THRESHOLD of those); call where
        the loop has slack. Generation 2 (everything older) is never collected inside the section."""
        young, middle, _ = gc.get_count()
        if young < YOUNG_THRESHOLD:
            return
        start = time.perf_counter()
        gc.collect(1 if middle >= MIDDLE_THRESHOLD else 0)
        self.pauses.add(time.perf_counter() - start)

    def settle(self) -> None:
        """Collect and freeze what was built since the section began (call once, when set-up is over and before the
        first DRIVE): otherwise the first safe point would pay for it (23.5 ms measured after the identification's
        set-up, more than the rig's watchdog)."""
        gc.collect()
        gc.freeze()

    def report(self) -> dict:
        """What the section did: its collections' pauses [s] and whether memory was locked (and if not, why)."""
        return {"gc_pauses": self.pauses.report(), "memory_locked": self.memory_locked,
                **({"memory_lock_note": self.memory_lock_note} if self.memory_lock_note else {})}


def lock_memory() -> str:
    """Lock the pages the process has mapped (its code, its libraries, its heap so far) in RAM as they are touched
    (``mlockall(MCL_CURRENT | MCL_ONFAULT)``), so that memory pressure cannot evict the loop's code and data for a
    page fault to read back; returns "" if done, else why not (the loop runs anyway). Later allocations are left
    alone (MCL_FUTURE would lock every one the process ever makes).

    Only where the system allows it: Linux, and a memlock limit that is unlimited (or root).
    """
    if not sys.platform.startswith("linux"):
        return "memory locking is Linux-only here"
    soft, _ = resource.getrlimit(resource.RLIMIT_MEMLOCK)
    if soft != resource.RLIM_INFINITY and os.geteuid() != 0:
        return (f"memory not locked: the memlock limit is {soft} bytes (allow 'memlock unlimited' for this user in "
                "/etc/security/limits.conf to lock it)")
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.mlockall(_MCL_CURRENT | _MCL_ONFAULT) != 0:
        return f"memory not locked: mlockall failed ({os.strerror(ctypes.get_errno())})"
    return ""


def _locked_kib() -> int:
    """The process's locked memory [KiB] (Linux: VmLck of /proc/self/status; 0 elsewhere)."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            return next((int(line.split()[1]) for line in status if line.startswith("VmLck:")), 0)
    except OSError:
        return 0


def unlock_memory() -> None:
    if sys.platform.startswith("linux"):
        ctypes.CDLL(None).munlockall()


@contextlib.contextmanager
def realtime_section(*, lock: bool = True) -> Iterator[SlackCollector]:
    """Run the block under the real-time discipline (module docstring); yields its :class:`SlackCollector`.

    Inside another section (the HardwareProxy FMU holds one from its initialisation to its termination, and a paced
    master around its loop; the FMU's copy of this module is not the master's, so the process's collector tells) this
    one changes nothing: its collector's safe points collect as the outer one's do."""
    if not gc.isenabled() and gc.get_freeze_count():
        locked = _locked_kib() > 0
        yield SlackCollector(memory_locked=locked,
                             memory_lock_note="" if locked else "inside another real-time section")
        return
    collector = SlackCollector()
    was_enabled, switch_interval = gc.isenabled(), sys.getswitchinterval()
    sys.setswitchinterval(min(switch_interval, SWITCH_INTERVAL_S))
    # frozen as it is, not collected first: a full collection walks every object the process holds (a late start in
    # a process that holds much), where freezing takes no time; settle() collects what set-up built since
    gc.freeze()
    gc.disable()
    if lock:
        collector.memory_lock_note = lock_memory()
        collector.memory_locked = not collector.memory_lock_note
    try:
        yield collector
    finally:
        if collector.memory_locked:
            unlock_memory()
        gc.unfreeze()
        if was_enabled:
            gc.enable()
        sys.setswitchinterval(switch_interval)


class BackgroundWriter:
    """A text file written by a daemon thread: :meth:`write` collects text in memory and :meth:`flush` hands what was
    collected to the thread; neither waits for the disk, and the thread wakes once per flush, not per write. A write
    the disk refused (OSError) is raised by the next :meth:`write` or :meth:`flush`, or by :meth:`close`, which
    waits until everything is on disk and closes ``file``."""

    def __init__(self, file: TextIO) -> None:
        self.file = file
        self.error: OSError | None = None
        self._pending: list[str] = []
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._drain, name=f"nfal-writer {getattr(file, 'name', '')}",
                                        daemon=True)
        self._thread.start()

    def write(self, text: str) -> None:
        self._raise_error()
        self._pending.append(text)

    def flush(self) -> None:
        self._raise_error()
        self._queue.put("".join(self._pending))
        self._pending.clear()

    def close(self) -> None:
        """Write what is collected, close the file; raise the disk's refusal, if any."""
        if self._thread.is_alive():
            self._queue.put("".join(self._pending))
            self._pending.clear()
            self._queue.put(None)
            self._thread.join()
        try:
            self.file.close()
        except OSError as exc:
            self.error = self.error or exc
        self._raise_error()

    def _raise_error(self) -> None:
        if self.error is not None:
            raise self.error

    def _drain(self) -> None:
        while (text := self._queue.get()) is not None:
            try:
                self.file.write(text)
                self.file.flush()
            except OSError as exc:
                self.error = exc
                return


def steal_s() -> float | None:
    """CPU time the hypervisor has taken from this machine's vCPUs since boot [s] (/proc/stat's steal, summed over the
    vCPUs, in 10 ms ticks); None where the system does not say."""
    try:
        with open("/proc/stat", encoding="ascii") as handle:
            fields = handle.readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


class StealWatch:
    """The hypervisor's share of this machine's vCPUs while a loop runs, from :meth:`sample` called now and then (every
    50 ms, say): over the whole watch, in its worst :data:`WINDOW_S`, and in the last one before :meth:`report`.
    A share is of all the vCPUs (100 % = every vCPU taken); None where the system does not say."""

    WINDOW_S = 1.0

    def __init__(self) -> None:
        self._recent: collections.deque = collections.deque()  # (time, steal): the last WINDOW_S and one before
        self._first: tuple[float, float] | None = None
        self._worst: tuple[float, float] | None = None  # (share, seconds after the first sample at the window's end)
        self._cpus = os.cpu_count() or 1

    def sample(self, now: float | None = None, stolen: float | None = None) -> None:
        stolen = steal_s() if stolen is None else stolen
        if stolen is None:
            return
        now = time.monotonic() if now is None else now
        recent = self._recent
        if len(recent) >= 2 and now - recent[-2][0] < self.WINDOW_S / 20:
            recent[-1] = (now, stolen)  # the newest kept, at most ~20 a window: bounded whatever the caller's rate
        else:
            recent.append((now, stolen))
        self._first = self._first or (now, stolen)
        while len(recent) > 2 and recent[1][0] <= now - self.WINDOW_S:
            recent.popleft()
        share = self._share(*recent[0], now, stolen)
        if share is not None and now - recent[0][0] >= self.WINDOW_S and (self._worst is None
                                                                         or share > self._worst[0]):
            self._worst = (share, now - self._first[0])

    def _share(self, since: float, stolen_then: float, now: float, stolen: float) -> float | None:
        return None if now <= since else 100 * (stolen - stolen_then) / ((now - since) * self._cpus)

    def report(self) -> dict:
        """``{"share_percent", "worst_second_percent", "worst_second_at_s", "last_second_percent"}``: over the watch,
        its worst second (and when it ended, from the first sample), the last second (None: not measured)."""
        if self._first is None:
            return {"share_percent": None, "worst_second_percent": None, "worst_second_at_s": None,
                    "last_second_percent": None}
        now, stolen = self._recent[-1]
        worst, at = self._worst or (None, None)
        return {"share_percent": self._share(*self._first, now, stolen), "worst_second_percent": worst,
                "worst_second_at_s": at, "last_second_percent": self._share(*self._recent[0], now, stolen)}
