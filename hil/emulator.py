"""The rig emulator (``nfal rig-emulator``): the rig's firmware and hardware, in real time, on a port.

Each tick of the rig's sample clock (released on the wall clock by
:class:`~nfal.orchestration.pacing.RealTimePacer`; a tick more than ``RESYNC_AFTER_S`` late, when the
machine was busy elsewhere, restarts the schedule from then, so the rig's physics never runs faster
than real time: the host sees the stall as samples that did not come):

1. read what the host sent and hand it to the :class:`~nfal.hil.firmware.Firmware` (HELLO, DRIVE, STOP);
2. the firmware decides the voltage for this period (command, limit, watchdog ramp);
3. the rig model (:mod:`nfal.hil.rig_model`: the rig structure's blocks) takes it, and its sensors are read;
4. MEASUREMENT (and, when due, RIG_HEARTBEAT and any FAULT) go out through the
   :class:`~nfal.hil.faults.FaultInjector`;
5. the rig model advances one period.

``disconnect_at_s`` drops the port at that wall time after the start (the host's reads fail) and
reconnects it ``reconnect_after_s`` later; the rig keeps running meanwhile, so its watchdog ramps the
drive down if the host stops commanding.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable

from nfal.models.errors import InvalidParameterError

from .faults import FaultInjector, FaultSettings
from .firmware import Firmware, RigTiming

logger = logging.getLogger(__name__)

#: A tick later than this [s] restarts the rig's schedule from now (RealTimePacer's resync_after_s).
RESYNC_AFTER_S = 0.002


@dataclasses.dataclass(frozen=True)
class Disconnection:
    """Drop the port ``at_s`` seconds of wall time after the start, reconnect ``after_s`` later (None: never)."""

    at_s: float
    after_s: float | None = 1.0

    def __post_init__(self) -> None:
        if not self.at_s >= 0:
            raise InvalidParameterError("disconnect_at_s", self.at_s, ">= 0 s")
        if self.after_s is not None and not self.after_s > 0:
            raise InvalidParameterError("reconnect_after_s", self.after_s, "> 0 s, or None to stay disconnected")


@dataclasses.dataclass
class EmulatorReport:
    """What a run of the emulator did (for the exit summary and the benchmark)."""

    ticks: int = 0
    frames_sent: int = 0
    disconnects: int = 0
    final_voltage: float = 0.0
    pacing: dict = dataclasses.field(default_factory=dict)
    faults: dict = dataclasses.field(default_factory=dict)
    decoder: dict = dataclasses.field(default_factory=dict)
    bytes_dropped: int = 0


class Emulator:
    """The rig on ``port`` (a :class:`~nfal.hil.ports.PtyPort` or :class:`~nfal.hil.ports.UrlPort`).

    Parameters
    ----------
    port
        Where the host is.
    model : InProcessRig or StructureRig
        The rig's hardware, stepped at ``timing.sample_period_s``.
    timing : RigTiming
    faults : FaultSettings
    disconnection : Disconnection, optional
    on_event : callable, optional
        ``on_event(text)`` for a line of the emulator's log (session, watchdog, link events).
    """

    def __init__(self, port, model, *, timing: RigTiming = RigTiming(), faults: FaultSettings = FaultSettings(),
                 disconnection: Disconnection | None = None, on_event: Callable[[str], None] | None = None) -> None:
        self.port, self.model, self.timing = port, model, timing
        self.on_event = on_event or (lambda text: logger.info("%s", text))
        self.firmware = Firmware(timing, on_event=lambda t, text: self.on_event(f"t = {t:.4f} s: {text}"))
        self.inject = FaultInjector(faults)
        self.disconnection = disconnection
        self.report = EmulatorReport()
        self._stop = False

    def stop(self) -> None:
        """Ask :meth:`run` to return after the current tick (from a signal handler or another thread)."""
        self._stop = True

    def tick(self, k: int, wall_s: float) -> None:
        """One sample period of the rig (see the module docstring)."""
        firmware, port = self.firmware, self.port
        out = firmware.receive(port.read(), k)
        voltage, faults = firmware.voltage(k)
        out += faults
        self.model.apply(voltage)
        out += firmware.report(k, self.model.reading())
        frames = self.inject(out, wall_s)
        if frames:
            port.write(b"".join(frames))
            self.report.frames_sent += len(frames)
        self.model.advance()

    def _link_events(self, elapsed_s: float, dropped_at: float | None) -> float | None:
        plan = self.disconnection
        if plan is None:
            return dropped_at
        if dropped_at is None and self.port.connected and elapsed_s >= plan.at_s and not self.report.disconnects:
            self.port.disconnect()
            self.report.disconnects += 1
            self.on_event(f"wall {elapsed_s:.3f} s: port disconnected (rig time {self.model.time:.4f} s)")
            return elapsed_s
        if dropped_at is not None and plan.after_s is not None and elapsed_s >= dropped_at + plan.after_s:
            self.port.connect()
            self.on_event(f"wall {elapsed_s:.3f} s: port reconnected at {self.port.path}")
            return None
        return dropped_at

    def run(self, duration_s: float | None = None) -> EmulatorReport:
        """Tick in real time until ``duration_s`` of wall time (None: until :meth:`stop`)."""
        from nfal.orchestration.pacing import RealTimePacer

        period = self.timing.sample_period_s
        # sleep only (no busy wait): the rig needs no microsecond release, and the host beside it needs the CPU;
        # after a stall the rig's clock goes on from now (a burst of ticks would run its physics too fast)
        pacer = RealTimePacer(period, spin_s=0.0, history=int(60 / period), resync_after_s=RESYNC_AFTER_S)
        ticks = None if duration_s is None else max(1, round(duration_s / period))
        dropped_at = None
        pacer.start()
        k = 0
        while not self._stop and (ticks is None or k < ticks):
            pacer.wait(k)
            elapsed = k * period
            dropped_at = self._link_events(elapsed, dropped_at)
            self.tick(k, elapsed)
            pacer.done(k)
            k += 1
        report = self.report
        report.ticks, report.final_voltage = k, self.firmware.applied
        report.pacing = pacer.report()
        report.faults = dataclasses.asdict(self.inject.counts)
        report.decoder = self.firmware.decoder.counters.as_dict()
        report.bytes_dropped = self.port.bytes_dropped
        return report
