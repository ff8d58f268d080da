"""The rig's side of the protocol as firmware would run it: :class:`Firmware`, one sample tick at a time.

Transport-free and clock-free: bytes from the host go in (:meth:`Firmware.receive`), frames for the host
come out, and time is the tick count k (rig time k * sample period). It decides the voltage the rig
applies in each period, per docs/protocol.md:

* DRIVE sets the commanded voltage (clamped to ``max_drive_voltage``: DRIVE_LIMITED) and feeds the
  watchdog; the first DRIVE arms it. Before any DRIVE the rig applies 0 V.
* No DRIVE for ``watchdog_timeout_s`` while armed trips the watchdog: FAULT(WATCHDOG), WATCHDOG_TRIPPED,
  and the applied voltage ramps linearly from its last value to 0 V over ``ramp_down_s``, then holds 0 V;
  DRIVE is ignored until the next HELLO. STOP ends the session with the same ramp. A HELLO while a
  drive is in force leaves it in force (a host reconnecting within the watchdog time takes over).
* HELLO opens a session (HELLO_ACK, or FAULT(VERSION_MISMATCH) for another version); MEASUREMENT goes
  out every tick of a session; RIG_HEARTBEAT every ``heartbeat_period_s``, in a session or not.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

from nfal.errors import InvalidParameterError, require_positive

from .protocol import (HOST_TO_RIG, PROTOCOL_VERSION, Drive, Fault, FaultCode, FrameDecoder, FrameEncoder, Hello,
                       HelloAck, HostHeartbeat, Measurement, RigHeartbeat, StatusFlags, Stop)


@dataclasses.dataclass(frozen=True)
class RigTiming:
    """The rig's announced timing and limits (HELLO_ACK), SI."""

    sample_period_s: float = 5e-4
    watchdog_timeout_s: float = 0.1
    ramp_down_s: float = 0.05
    max_drive_voltage: float = 150.0
    heartbeat_period_s: float = 0.1

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):
            require_positive(field.name, getattr(self, field.name))
        if self.watchdog_timeout_s < 2 * self.sample_period_s:
            raise InvalidParameterError("watchdog_timeout_s", self.watchdog_timeout_s,
                                        f">= two sample periods ({2 * self.sample_period_s:g} s)")

    def hello_ack(self) -> HelloAck:
        return HelloAck(PROTOCOL_VERSION, round(self.sample_period_s * 1e6), round(self.watchdog_timeout_s * 1e6),
                        round(self.ramp_down_s * 1e6), self.max_drive_voltage)


@dataclasses.dataclass(frozen=True)
class RigReading:
    """What the rig's hardware reports at a tick (the emulator's rig model, or real sensors)."""

    height: float
    drive_frequency: float
    locked: bool
    resting: bool


class Firmware:
    """The protocol state machine and watchdog (see the module docstring).

    Parameters
    ----------
    timing : RigTiming
    on_event : callable, optional
        ``on_event(rig_time_s, text)`` for what a rig would log (session, watchdog, faults).
    """

    def __init__(self, timing: RigTiming = RigTiming(), on_event: Callable[[float, str], None] | None = None) -> None:
        self.timing = timing
        self.on_event = on_event or (lambda t, text: None)
        self.decoder = FrameDecoder(HOST_TO_RIG)
        self.encoder = FrameEncoder()
        self.session = False
        self.armed = False          # a DRIVE has come in this session
        self.tripped = False
        self.limited = False
        self.commanded = 0.0        # [V], after the clamp
        self.applied = 0.0          # [V] over the current period
        self.command_seq = 0
        self.drives = 0             # DRIVE commands taken (the lockstep emulator ticks on them)
        self.last_measurement: Measurement | None = None
        self._last_drive_tick = 0
        self._ramp: tuple[int, float] | None = None  # (start tick, start voltage)
        self._watchdog_ticks = math.ceil(timing.watchdog_timeout_s / timing.sample_period_s - 1e-9)
        self._ramp_ticks = max(1, round(timing.ramp_down_s / timing.sample_period_s))
        self._heartbeat_ticks = max(1, round(timing.heartbeat_period_s / timing.sample_period_s))

    def _time(self, tick: int) -> float:
        return tick * self.timing.sample_period_s

    def _us(self, tick: int) -> int:
        return round(tick * self.timing.sample_period_s * 1e6)

    # --- host -> rig --------------------------------------------------------------------------------
    def receive(self, data: bytes, tick: int) -> list[bytes]:
        """Take the host's bytes at ``tick``; return the frames to answer with."""
        out: list[bytes] = []
        dropped_before = self.decoder.counters.dropped
        for received in self.decoder.feed(data):
            message = received.message
            if isinstance(message, Hello):
                out += self._hello(message, tick)
            elif isinstance(message, Drive):
                out += self._drive(message, received.seq, tick)
            elif isinstance(message, Stop):
                if self.session:
                    self.on_event(self._time(tick), "STOP: session ended, drive ramping down")
                    if self._ramp is None:  # a ramp already running (a tripped watchdog's) runs on as it is
                        self._start_ramp(tick)
                self.session = self.armed = False
            elif isinstance(message, HostHeartbeat):
                pass
        if self.decoder.counters.dropped > dropped_before:
            out.append(self.encoder(Fault(self._us(tick), FaultCode.BAD_FRAME, float(self.decoder.counters.dropped))))
        return out

    def _hello(self, hello: Hello, tick: int) -> list[bytes]:
        if hello.protocol_version != PROTOCOL_VERSION:
            self.on_event(self._time(tick), f"HELLO for protocol {hello.protocol_version}: refused")
            return [self.encoder(Fault(self._us(tick), FaultCode.VERSION_MISMATCH, float(hello.protocol_version)))]
        self.encoder.restart()
        # a drive in force stays in force (the watchdog keeps counting): a host that reconnects within the
        # watchdog time takes over without a bump; a trip is cleared (the ramp, if any, runs on)
        if self.tripped:  # cleared: 0 V (after the ramp) until the next DRIVE
            self.armed = False
        self.session, self.tripped, self.limited = True, False, False
        self.on_event(self._time(tick), "HELLO: session open")
        return [self.encoder(self.timing.hello_ack())]

    def _drive(self, drive: Drive, seq: int, tick: int) -> list[bytes]:
        if not self.session or self.tripped:
            return []  # outside a session, or tripped until the next HELLO
        voltage = drive.voltage  # >= 0 and finite: the decoder drops anything else
        out = []
        limited = voltage > self.timing.max_drive_voltage
        if limited and not self.limited:
            out.append(self.encoder(Fault(self._us(tick), FaultCode.DRIVE_LIMITED, voltage)))
        self.limited = limited
        self.commanded = min(voltage, self.timing.max_drive_voltage)
        self.command_seq, self._last_drive_tick = seq, tick
        self.armed, self._ramp = True, None
        self.drives += 1
        return out

    # --- the rig's clock ----------------------------------------------------------------------------
    def voltage(self, tick: int) -> tuple[float, list[bytes]]:
        """The voltage applied over the period starting at ``tick`` [V], and any FAULT to send."""
        out: list[bytes] = []
        if self.armed and not self.tripped and tick - self._last_drive_tick >= self._watchdog_ticks:
            self.tripped = True
            silent = self._time(tick - self._last_drive_tick)
            self.on_event(self._time(tick), f"watchdog: no DRIVE for {silent * 1e3:.1f} ms, drive ramping down "
                          f"from {self.applied:.3g} V over {self.timing.ramp_down_s * 1e3:g} ms")
            out.append(self.encoder(Fault(self._us(tick), FaultCode.WATCHDOG, silent)))
            self._start_ramp(tick)
        if self._ramp is not None:
            start, from_voltage = self._ramp
            fraction = min(1.0, (tick - start) / self._ramp_ticks)
            self.applied = from_voltage * (1.0 - fraction)
            if fraction >= 1.0:
                self._ramp = None
                self.commanded = 0.0
                self.on_event(self._time(tick), "drive down: 0 V")
        elif self.armed and not self.tripped:
            self.applied = self.commanded
        else:
            self.applied = 0.0
        return self.applied, out

    def _start_ramp(self, tick: int) -> None:
        self._ramp = (tick, self.applied)
        self.commanded = 0.0

    def status(self, reading: RigReading | None = None) -> int:
        flags = StatusFlags(0)
        if self.session:
            flags |= StatusFlags.SESSION_ACTIVE
        if self.tripped:
            flags |= StatusFlags.WATCHDOG_TRIPPED
        if self.limited:
            flags |= StatusFlags.DRIVE_LIMITED
        if reading is not None and reading.locked:
            flags |= StatusFlags.PLL_LOCKED
        if reading is not None and reading.resting:
            flags |= StatusFlags.RESTING
        return int(flags)

    def report(self, tick: int, reading: RigReading) -> list[bytes]:
        """The frames for the host at ``tick``: MEASUREMENT in a session, RIG_HEARTBEAT when due."""
        out = []
        if self.session:
            self.last_measurement = Measurement(self._us(tick), reading.height, reading.drive_frequency, self.applied,
                                                self.status(reading), self.command_seq)
            out.append(self.encoder(self.last_measurement))
        if tick % self._heartbeat_ticks == 0:
            counters = self.decoder.counters
            out.append(self.encoder(RigHeartbeat(self._us(tick), self.status(reading), counters.frames_ok,
                                                 counters.dropped)))
        return out
