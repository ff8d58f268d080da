"""The rig as ``nfal identify``'s experiments see it: a :class:`RigIO` exchanges a drive for the samples measured
since. :class:`LinkRig` is one over the rig protocol (:class:`~nfal.hil.link.RigLink`, any pyserial URL); a simulated
rig in the tests is another. The link's real-time margin (gaps between DRIVE commands, the age of the newest sample
when its answer left) is :meth:`LinkRig.timing`'s.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, Protocol

from nfal.errors import ExperimentError
from nfal.hil.link import RigLink, Sample
from nfal.hil.protocol import StatusFlags
from nfal.realtime import LatencyStats

#: Longest silence of the rig before the link counts as lost [s] (a loaded host can pause the emulator ~0.1 s).
MAX_SILENCE_S = 0.5
#: Longest wait for the port between two checks of the link [s].
SILENCE_CHECK_S = 0.01


@dataclasses.dataclass(frozen=True)
class RigSample:
    """One measurement: rig time [s], height [m], drive frequency [Hz], applied voltage [V], resting, watchdog."""

    time_s: float
    height_m: float
    drive_frequency_hz: float
    applied_voltage_v: float
    resting: bool
    watchdog_tripped: bool = False


class RigIO(Protocol):
    """Send the drive for the next period, get the samples measured since the last call (at least one); call
    ``safe_point`` right after the drive left; ``timing`` reports the loop's margin (:meth:`LinkRig.timing`)."""

    safe_point: Callable[[], None]

    def exchange(self, voltage: float) -> list[RigSample]: ...

    def timing(self) -> dict: ...

    def close(self) -> None: ...


class LinkRig:
    """:class:`RigIO` over a :class:`RigLink` (opened here; closed with STOP by :meth:`close`).

    ``safe_point`` (default: nothing) is called right after each DRIVE left, where the loop has the most slack before
    the next sample (a real-time section's collector); :attr:`lateness` holds the age of the newest sample when the
    DRIVE answering it left, and the link's ``drive_gaps`` the gaps between DRIVE commands."""

    def __init__(self, url: str, *, connect_timeout_s: float = 2.0, max_silence_s: float = MAX_SILENCE_S) -> None:
        self._new: list[RigSample] = []
        self._newest_arrival: float | None = None
        self.lateness = LatencyStats()
        self.safe_point: Callable[[], None] = lambda: None
        self.link = RigLink(url, connect_timeout_s=connect_timeout_s, reconnect=False, reader_thread=False,
                            on_sample=self._take)
        self.hello = self.link.open()
        self.max_silence_s = max_silence_s

    def _take(self, sample: Sample) -> None:
        m = sample.measurement
        self._newest_arrival = sample.arrival_s
        self._new.append(RigSample(m.timestamp_us * 1e-6, m.height, m.drive_frequency, m.drive_voltage,
                                   bool(m.status & StatusFlags.RESTING), bool(m.status & StatusFlags.WATCHDOG_TRIPPED)))

    def exchange(self, voltage: float) -> list[RigSample]:
        link = self.link
        if self._newest_arrival is not None:
            self.lateness.add(link.clock() - self._newest_arrival)
        link.send_drive(voltage)
        self.safe_point()
        deadline = link.clock() + self.max_silence_s
        while True:
            link.poll()
            if self._new:
                new, self._new = self._new, []
                return new
            now = link.clock()
            if now > deadline or not link.connected:
                reason = link.last_error or "the rig fell silent"
                raise ExperimentError(f"link lost: no measurement from {link.url} for "
                                      f"{self.max_silence_s * 1e3:.0f} ms ({reason})")
            link.wait_readable(min(deadline - now, SILENCE_CHECK_S))

    def timing(self) -> dict:
        """The margin to the rig's watchdog: gaps between DRIVE commands leaving the host, and the age of the newest
        sample when the DRIVE answering it left [s] (count, mean, p50, p99, max)."""
        return {"drive_gaps": self.link.drive_gaps.report(), "sample_to_drive": self.lateness.report()}

    def close(self) -> None:
        self.link.close()
