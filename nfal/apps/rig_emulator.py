"""The rig emulator (``nfal rig-emulator``): the rig's firmware and hardware, in real time, on a port.

Each tick of the rig's sample clock (released on the wall clock by
:class:`~nfal.orchestration.pacing.RealTimePacer`; a tick more than ``RESYNC_AFTER_S`` late, when the
machine was busy elsewhere, restarts the schedule from then, so the rig's physics never runs faster
than real time: the host sees the stall as samples that did not come):

1. read what the host sent and hand it to the :class:`~nfal.hil.firmware.Firmware` (HELLO, DRIVE, STOP);
2. the firmware decides the voltage for this period (command, limit, watchdog ramp);
3. the rig model (:mod:`nfal.apps.rig_model`: the rig structure's blocks) takes it, and its sensors are read;
4. MEASUREMENT (and, when due, RIG_HEARTBEAT and any FAULT) go out through the
   :class:`~nfal.hil.faults.FaultInjector`;
5. the rig model advances one period.

:class:`Disconnection` drops the port that long after the host's first DRIVE (the host's reads fail)
and reconnects it ``after_s`` later (rig time); the rig keeps running meanwhile, so its watchdog ramps
the drive down when the host stops commanding.

With ``lockstep`` the host's DRIVE commands are the rig's clock: once a session's first DRIVE has come,
each tick waits for the next one (up to ``LOCKSTEP_WAIT_S`` of wall time, then the rig ticks on the wall
clock again until the next DRIVE). A host whose HardwareProxy waits for each answer (``proxy.lockstep``)
then runs the same loop whatever the machine's load: for tests and debugging, not for timing. With the C firmware
(an :class:`~nfal.hil.plant_channel.ExternalFirmware` in tunnel mode, whose every tick takes the host's bytes) the
emulator holds the host's bytes until a DRIVE is among them (:class:`HostCommands` reads them as the rig will) and
hands them over with the tick they release.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Sequence
from typing import TextIO

from nfal.errors import InvalidParameterError, LinkError
from nfal.hil.faults import FaultInjector, FaultSettings
from nfal.hil.firmware import Firmware, RigTiming
from nfal.hil.protocol import HOST_TO_RIG, Drive, FrameDecoder, Hello, Stop
from nfal.orchestration.pacing import RealTimePacer
from nfal.realtime import realtime_section

logger = logging.getLogger(__name__)

#: The columns of the emulator's record (``--record``): what the rig measured and applied, and the truth.
RECORD_HEADER = "timestamp_us,height_m,drive_frequency_hz,applied_voltage_v,true_height_m"
#: A tick later than this [s] restarts the rig's schedule from now (RealTimePacer's resync_after_s).
RESYNC_AFTER_S = 0.002
#: The least the paced ticks sleep between them [s], late or not: the emulator runs at a real-time priority, and a late
#: one ran its ticks back to back (for 22-105 ms in issue 23's traced runs), while the kernel work that delivers its
#: frames to the host, queued on the same CPU, waited (docs/hil.md, "The emulator made to yield").
MIN_SLEEP_S = 1e-4
#: In lockstep, wall time the rig waits for the host's next DRIVE before ticking on its own clock again [s].
LOCKSTEP_WAIT_S = 5.0
#: In lockstep, the longest the rig waits without looking whether it was asked to stop [s].
STOP_CHECK_S = 0.1
#: Rig time between attempts to reopen a port that failed under the emulator (an unplugged device) [s].
REOPEN_INTERVAL_S = 0.5


class HostCommands:
    """The host's bytes held for a firmware that takes them only with a tick, read as the rig will read them: the
    DRIVE commands among them are counted (:attr:`drives`), a DRIVE, STOP or HELLO releases a tick, and
    :meth:`release` hands the bytes over."""

    def __init__(self) -> None:
        self.decoder = FrameDecoder(HOST_TO_RIG)
        self.drives = 0
        self._held = bytearray()

    def take(self, data: bytes) -> bool:
        """Hold ``data``; True if a DRIVE, a STOP or a HELLO came in it."""
        self._held += data
        commands = [r.message for r in self.decoder.feed(data) if isinstance(r.message, (Drive, Stop, Hello))]
        self.drives += sum(isinstance(m, Drive) for m in commands)
        return bool(commands)

    def release(self) -> bytes:
        held, self._held = bytes(self._held), bytearray()
        return held


@dataclasses.dataclass(frozen=True)
class Disconnection:
    """Drop the port ``at_s`` seconds (rig time) after the host's first DRIVE, when its loop runs (a host's set-up
    takes a time that depends on the machine's load), and reconnect ``after_s`` later (None: never)."""

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
    lockstep_ticks: int = 0  #: ticks released by a DRIVE, not by the wall clock


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
    record : text file, optional
        Gets one CSV line per MEASUREMENT the rig takes in a session (before fault injection): :data:`RECORD_HEADER`.
    firmware : optional
        The rig's firmware, if not the Python one: an :class:`~nfal.hil.plant_channel.ExternalFirmware` (the C
        reference firmware, on the host or in QEMU), whose events go to ``on_event`` too.
    lockstep : bool
        Tick on the host's DRIVE commands (see the module docstring); an external firmware must then take the host's
        bytes through the emulator (tunnel mode).
    """

    def __init__(self, port, model, *, timing: RigTiming = RigTiming(), faults: FaultSettings = FaultSettings(),
                 disconnection: Disconnection | None = None, on_event: Callable[[str], None] | None = None,
                 record: TextIO | None = None, firmware=None, lockstep: bool = False) -> None:
        if lockstep and firmware is not None and not firmware.tunnel:
            raise InvalidParameterError("lockstep", lockstep, "False with an external firmware on its own serial line "
                                        "(the emulator does not see the host's DRIVE commands): use tunnel mode")
        #: an external firmware's host bytes, held until a tick takes them (lockstep)
        self._held = HostCommands() if lockstep and firmware is not None else None
        self.port, self.model, self.timing, self.lockstep = port, model, timing, lockstep
        self.on_event = on_event or (lambda text: logger.info("%s", text))
        firmware_event = lambda t, text: self.on_event(f"t = {t:.4f} s: {text}")  # noqa: E731
        if firmware is None:
            firmware = Firmware(timing, on_event=firmware_event)
        else:
            firmware.on_event = firmware_event
        self.firmware = firmware
        self.inject = FaultInjector(faults)
        self.disconnection = disconnection
        self.report = EmulatorReport()
        self._stop = False
        self._driven_at: float | None = None  # rig time of the first DRIVE
        self._dropped_at: float | None = None
        self._planned_done = False  # the planned disconnection has happened
        self._failures_seen = 0
        self._reopen_at = 0.0
        self._silent_after: int | None = None  # lockstep: the DRIVE count when the host went silent
        self._record = record
        if record is not None:
            record.write(RECORD_HEADER + "\n")

    def stop(self) -> None:
        """Ask :meth:`run` to return after the current tick (from a signal handler or another thread)."""
        self._stop = True

    def tick(self, k: int, received: Sequence[bytes] = ()) -> None:
        """One sample period of the rig (see the module docstring); ``received``: the firmware's answers to what
        came in while the tick waited for it (lockstep)."""
        firmware, port = self.firmware, self.port
        now = k * self.timing.sample_period_s
        data = port.read()
        if self._held is not None:  # what the lockstep wait held, first
            self._held.take(data)
            data = self._held.release()
        out = firmware.receive(data, k)
        if received:
            out = [*received, *out]
        if firmware.armed and self._driven_at is None:
            self._driven_at = now
        voltage, faults = firmware.voltage(k)
        out += faults
        self.model.apply(voltage)
        reading = self.model.reading()
        out += firmware.report(k, reading)
        if self._record is not None and firmware.session:
            self._record.write(f"{firmware.last_measurement.timestamp_us},{reading.height!r},"
                               f"{reading.drive_frequency!r},{voltage!r},{self.model.true_height!r}\n")
        frames = self.inject(out, now)
        if frames:
            # lockstep: the host waits for this answer, so the rig waits for room for it (a host that set up for a
            # while finds the port full of what was streamed meanwhile; a dropped answer would stall both ends)
            port.write(b"".join(frames), wait_s=LOCKSTEP_WAIT_S if self._ticks_on_drives() else 0.0)
            self.report.frames_sent += len(frames)
        self.model.advance()
        self._link_events(now)

    def _ticks_on_drives(self) -> bool:
        """Lockstep, in a session the host drives: unless the host went silent (until its next DRIVE)."""
        firmware = self.firmware
        if not (self.lockstep and firmware.armed and firmware.session):
            return False
        return (firmware.drives if self._held is None else self._held.drives) != self._silent_after

    def _await_drive(self, k: int) -> tuple[list[bytes], bool]:
        """Lockstep: take in what the host sends until a DRIVE (or a STOP) has come for tick ``k``. Returns the
        firmware's answers and whether one came within LOCKSTEP_WAIT_S."""
        firmware, port, held = self.firmware, self.port, self._held
        drives, out = firmware.drives if held is None else held.drives, []
        deadline = time.perf_counter() + LOCKSTEP_WAIT_S
        while not self._stop:
            if held is not None:  # the C firmware takes the host's bytes with its tick: hold them until a command
                if held.take(port.read()):
                    return out, True
            else:
                out += firmware.receive(port.read(), k)
                if firmware.drives != drives or not firmware.session:
                    return out, True
            remaining = deadline - time.perf_counter()
            if remaining <= 0:
                self._silent_after = drives  # the wall clock until the next DRIVE
                self.on_event(f"t = {k * self.timing.sample_period_s:.4f} s: lockstep: no DRIVE for "
                              f"{LOCKSTEP_WAIT_S:g} s, ticking on the wall clock")
                break
            port.wait_readable(min(remaining, STOP_CHECK_S))  # a stop() (a signal's) is seen within STOP_CHECK_S
        return out, False

    def _link_events(self, now_s: float) -> None:
        """Drop or restore the port as ``disconnection`` says (rig time since the first DRIVE); reopen
        one that failed under us every REOPEN_INTERVAL_S."""
        port = self.port
        if port.failures != self._failures_seen:
            self._failures_seen = port.failures
            self.report.disconnects += 1
            self.on_event(f"t = {now_s:.4f} s: port failed: {port.last_error}")
        if not port.connected and self._dropped_at is None and now_s >= self._reopen_at:
            self._connect(now_s, "reopened")
        plan, driven = self.disconnection, self._driven_at
        if plan is None or driven is None:
            return
        if self._dropped_at is None and not self._planned_done and now_s - driven >= plan.at_s:
            self.port.disconnect()
            self.report.disconnects += 1
            self._dropped_at, self._planned_done = now_s, True
            self.on_event(f"t = {now_s:.4f} s: port disconnected")
        elif self._dropped_at is not None and plan.after_s is not None and now_s >= self._dropped_at + plan.after_s:
            self._dropped_at = None  # if this fails, the port is reopened as any failed one
            self._connect(now_s, "reconnected")

    def _connect(self, now_s: float, event: str) -> None:
        """Connect the port (logging ``port <event>``); if that fails, try again REOPEN_INTERVAL_S later."""
        self._reopen_at = now_s + REOPEN_INTERVAL_S
        try:
            self.port.connect()
        except LinkError as exc:
            self.port.last_error = str(exc)
            return
        self.on_event(f"t = {now_s:.4f} s: port {event} at {self.port.path}")

    def run(self, duration_s: float | None = None) -> EmulatorReport:
        """Tick in real time until ``duration_s`` of wall time (None: until :meth:`stop`)."""
        period = self.timing.sample_period_s
        # sleep only (no busy wait), and at least MIN_SLEEP_S a tick: the rig needs no microsecond release, and the
        # host beside it needs the CPU; after a stall the rig's clock goes on from now (a burst of ticks would run its
        # physics too fast)
        pacer = RealTimePacer(period, spin_s=0.0, resync_after_s=RESYNC_AFTER_S, min_sleep_s=MIN_SLEEP_S)
        ticks = None if duration_s is None else max(1, round(duration_s / period))
        k = 0
        with realtime_section() as collector:  # the collector runs between ticks only (nfal.realtime)
            collector.settle()
            pacer.start()
            stepped = False  # the last tick was released by a DRIVE
            while not self._stop and (ticks is None or k < ticks):
                received, released = self._await_drive(k) if self._ticks_on_drives() else ([], False)
                if released:
                    self.tick(k, received)
                    self.report.lockstep_ticks += 1
                else:
                    if stepped:
                        pacer.restart(k)  # the wall clock again, from now
                    pacer.wait(k)
                    self.tick(k, received)
                    pacer.done(k)
                stepped = released
                collector.safe_point()
                k += 1
        if self._record is not None:
            self._record.flush()
        report = self.report
        report.ticks, report.final_voltage = k, self.firmware.applied
        report.pacing = {**pacer.report(), **collector.report()}
        report.faults = dataclasses.asdict(self.inject.counts)
        report.decoder = self.firmware.decoder.counters.as_dict()
        report.bytes_dropped = self.port.bytes_dropped
        return report
