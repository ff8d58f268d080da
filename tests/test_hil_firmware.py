"""The rig's firmware: session, drive, watchdog, clamp and bad frames, tick by tick: the conformance suite.

Every test runs against the three firmwares (``firmware`` parameter): the Python one (nfal.hil.firmware), the C
reference firmware built for the host, and the same C built for a Cortex-M4F running in QEMU (mps2-an386). The
C ones run in tunnel mode (nfal.hil.plant_channel): the host's bytes and the rig's frames ride the plant
channel, so each tick is exact. A firmware is clock-free and transport-free, so every check is exact, in rig
time: the host's frames come from a :class:`FrameEncoder`, the rig's answers go through a host-side
:class:`FrameDecoder`, and each tick runs receive -> voltage -> report, as the emulator does. Rules are those
of docs/protocol.md §6-§7. The C firmware computes in binary32 (a Cortex-M4F's FPU): voltages are compared to
binary32 precision (:func:`close`).
"""

from __future__ import annotations

import math
import struct

import pytest
from cobs import cobs

from nfal.errors import InvalidParameterError
from nfal.hil.firmware import Firmware, RigReading, RigTiming
from nfal.hil.plant_channel import FIRMWARES, TUNNEL_BYTES, ExternalFirmware, FirmwareProcess
from nfal.hil.protocol import (PROTOCOL_VERSION, RIG_TO_HOST, Drive, Fault, FaultCode, FrameDecoder, FrameEncoder,
                               Hello, HelloAck, HostHeartbeat, Measurement, Message, RigHeartbeat, StatusFlags, Stop,
                               encode)

pytestmark = pytest.mark.realtime  # the QEMU firmware's serial line: one at a time, on one worker (conftest.py)

#: Short, round timing: watchdog 5 ticks, ramp 4 ticks, heartbeat every 10 ticks (1 ms ticks).
FAST = RigTiming(sample_period_s=1e-3, watchdog_timeout_s=5e-3, ramp_down_s=4e-3, max_drive_voltage=150.0,
                 heartbeat_period_s=1e-2)
WATCHDOG_TICKS, RAMP_TICKS, HEARTBEAT_TICKS = 5, 4, 10
READING = RigReading(height=1e-4, drive_frequency=28_500.0, locked=True, resting=False)
SESSION, TRIPPED, LIMITED = StatusFlags.SESSION_ACTIVE, StatusFlags.WATCHDOG_TRIPPED, StatusFlags.DRIVE_LIMITED


def close(values: list[float]):
    """``values`` to binary32 precision (the C firmware ramps in binary32; the Python one in double)."""
    return pytest.approx(values, rel=2e-7, abs=1e-30)


def f32(x: float) -> float:
    """``x`` rounded to binary32, as it travels on the wire."""
    return struct.unpack("<f", struct.pack("<f", x))[0]


class Tick:
    """What one tick produced: the applied voltage and the rig's frames, as the host decoded them."""

    def __init__(self, voltage: float, received) -> None:
        self.voltage = voltage
        self.received = received
        self.messages = [r.message for r in received]

    def of(self, cls: type[Message]) -> list:
        return [m for m in self.messages if isinstance(m, cls)]

    def faults(self, code: FaultCode | None = None) -> list[Fault]:
        return [m for m in self.of(Fault) if code is None or m.code == code]

    @property
    def measurement(self) -> Measurement:
        [measurement] = self.of(Measurement)
        return measurement


class Bench:
    """A :class:`Firmware` beside a host encoder and a host decoder; :meth:`tick` runs one sample period."""

    def __init__(self, timing: RigTiming = FAST, reading: RigReading = READING, firmware=None) -> None:
        self.firmware = firmware if firmware is not None else Firmware(timing)
        self.host = FrameEncoder()
        self.decoder = FrameDecoder(RIG_TO_HOST)
        self.reading = reading
        self.k = 0
        self.sent_seqs: list[int] = []  # seq of every host frame, in order

    def frame(self, message: Message) -> bytes:
        self.sent_seqs.append(self.host.next_seq)
        return self.host(message)

    def tick(self, *messages: Message, raw: bytes = b"", reading: RigReading | None = None) -> Tick:
        firmware, k = self.firmware, self.k
        data = b"".join(self.frame(m) for m in messages) + raw
        out = firmware.receive(data, k)
        voltage, faults = firmware.voltage(k)
        out += faults
        out += firmware.report(k, reading or self.reading)
        self.k += 1
        return Tick(voltage, self.decoder.feed(b"".join(out)))

    def ticks(self, n: int, *messages: Message) -> list[Tick]:
        """``n`` ticks, ``messages`` sent at the first."""
        return [self.tick(*messages)] + [self.tick() for _ in range(n - 1)]

    def hello(self) -> Tick:
        self.host.restart()
        return self.tick(Hello(PROTOCOL_VERSION))


@pytest.fixture(scope="module")
def processes():
    """The C firmwares' processes, started on first use and kept for the module (each bench reboots its firmware)."""
    running: dict[str, FirmwareProcess] = {}
    yield running
    for process in running.values():
        process.close()


@pytest.fixture(params=FIRMWARES)
def make_bench(request, processes):
    """``make_bench(timing=FAST, reading=READING)``: a bench around the firmware of this parameter, fresh from reset."""
    kind = request.param

    def make(timing: RigTiming = FAST, reading: RigReading = READING) -> Bench:
        if kind == "python":
            return Bench(timing, reading)
        if kind not in processes:
            processes[kind] = FirmwareProcess(kind)
        return Bench(timing, reading, ExternalFirmware(processes[kind], timing))
    return make


@pytest.fixture
def bench(make_bench) -> Bench:
    return make_bench()


@pytest.fixture
def session(make_bench) -> Bench:
    """A bench with a session open (HELLO at tick 0)."""
    bench = make_bench()
    bench.hello()
    return bench


def voltages(ticks: list[Tick]) -> list[float]:
    return [t.voltage for t in ticks]


def ramp(v0: float, then: int = 2) -> list[float]:
    """§7: V0 * max(0, 1 - j / ramp) tick by tick from the trip, then ``then`` ticks of 0 V."""
    return [v0 * max(0.0, 1.0 - j / RAMP_TICKS) for j in range(RAMP_TICKS + 1 + then)]


# --- HELLO -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("timing, ack", [
    (RigTiming(), HelloAck(1, 500, 100_000, 50_000, 150.0)),
    (FAST, HelloAck(1, 1000, 5000, 4000, 150.0)),
    (RigTiming(2.5e-4, 0.01, 0.125, 80.5, 0.05), HelloAck(1, 250, 10_000, 125_000, 80.5)),
], ids=["emulator", "fast", "other"])
def test_hello_is_answered_with_hello_ack_in_microseconds_at_seq_0(make_bench, timing, ack):
    bench = make_bench(timing)
    for _ in range(3):  # the rig's counter moves on (a heartbeat at tick 0) before the host says HELLO
        bench.tick()
    assert bench.decoder.counters.frames_ok > 0
    answer = bench.hello()
    assert answer.messages[0] == ack and answer.received[0].seq == 0
    assert bench.firmware.session and answer.measurement.status & SESSION
    assert bench.decoder.counters.dropped == 0


@pytest.mark.parametrize("version", [0, 2, 0xFFFF])
def test_hello_for_another_version_is_refused_and_opens_nothing(bench, version):
    bench.tick()
    seq_before = bench.decoder.last_seq + 1  # the rig's next seq
    answer = bench.tick(Hello(version))
    assert answer.messages == [Fault(1000, FaultCode.VERSION_MISMATCH, float(version))]
    assert answer.received[0].seq == seq_before  # no restart: not a session opener
    assert not bench.firmware.session
    assert all(not t.of(Measurement) for t in bench.ticks(HEARTBEAT_TICKS))


def test_a_refused_hello_changes_nothing_in_an_open_session(session):
    session.tick(Drive(90.0))
    answer = session.tick(Hello(2))
    assert answer.faults() == [Fault(2000, FaultCode.VERSION_MISMATCH, 2.0)] and not answer.of(HelloAck)
    assert answer.voltage == 90.0 and answer.measurement.status & SESSION


# --- measurements, heartbeats, drive ---------------------------------------------------------------

@pytest.mark.parametrize("locked, resting, flags", [
    (False, False, 0), (True, False, StatusFlags.PLL_LOCKED), (False, True, StatusFlags.RESTING),
    (True, True, StatusFlags.PLL_LOCKED | StatusFlags.RESTING),
])
def test_a_session_measures_every_tick_with_the_readings_flags(make_bench, locked, resting, flags):
    reading = RigReading(1.25e-4, 28_400.0, locked, resting)
    bench = make_bench(reading=reading)
    bench.hello()
    ticks = bench.ticks(3)
    assert [t.measurement for t in ticks] == [
        Measurement(k * 1000, f32(1.25e-4), 28_400.0, 0.0, int(SESSION | flags), 0) for k in (1, 2, 3)]
    assert voltages(ticks) == [0.0] * 3  # before any DRIVE


def test_no_measurement_outside_a_session_but_heartbeats_always(bench):
    before = bench.ticks(2 * HEARTBEAT_TICKS)
    assert not any(t.of(Measurement) for t in before)
    beats = {k: t.of(RigHeartbeat) for k, t in enumerate(before) if t.of(RigHeartbeat)}
    assert list(beats) == [0, HEARTBEAT_TICKS]
    assert beats[HEARTBEAT_TICKS] == [RigHeartbeat(10_000, int(StatusFlags.PLL_LOCKED), 0, 0)]
    bench.hello()  # tick 20
    during = bench.ticks(HEARTBEAT_TICKS)  # ticks 21-30
    assert [k for k, t in enumerate(during, 21) if t.of(RigHeartbeat)] == [30]
    assert during[-1].of(RigHeartbeat) == [RigHeartbeat(30_000, int(StatusFlags.PLL_LOCKED | SESSION), 1, 0)]
    assert all(len(t.of(Measurement)) == 1 for t in during)


def test_heartbeats_keep_the_emulators_period(make_bench):
    bench = make_bench(RigTiming())
    ticks = bench.ticks(401)
    assert [k for k, t in enumerate(ticks) if t.of(RigHeartbeat)] == [0, 200, 400]


def test_drive_applies_from_that_tick_with_its_seq(session):
    assert session.tick().voltage == 0.0
    driven = session.tick(Drive(42.5))
    seq = session.sent_seqs[-1]
    assert driven.voltage == 42.5 == session.firmware.applied
    assert driven.measurement.drive_voltage == 42.5 and driven.measurement.command_seq == seq == 1
    assert not driven.faults()
    assert voltages(session.ticks(WATCHDOG_TICKS - 1)) == [42.5] * (WATCHDOG_TICKS - 1)
    again = session.tick(Drive(10.0))
    assert again.voltage == 10.0 and again.measurement.command_seq == 2


def test_minus_zero_is_a_valid_zero(session):
    driven = session.tick(Drive(-0.0))
    assert driven.voltage == 0.0 and driven.measurement.command_seq == 1
    assert session.firmware.decoder.counters.invalid_value == 0 and session.firmware.armed


def test_drive_outside_a_session_is_ignored_but_counted(bench):
    ticks = bench.ticks(3, Drive(100.0))
    assert voltages(ticks) == [0.0] * 3 and bench.firmware.command_seq == 0 and not bench.firmware.armed
    assert bench.firmware.decoder.counters.frames_ok == 1
    assert all(not t.faults() for t in ticks)


# --- watchdog --------------------------------------------------------------------------------------

def trip(bench: Bench, v0: float) -> tuple[list[Tick], list[Tick]]:
    """DRIVE(v0) then silence: (the ticks before the trip, the ticks from the trip on, ramp + 2)."""
    before = bench.ticks(WATCHDOG_TICKS, Drive(v0))
    after = bench.ticks(RAMP_TICKS + 3)
    return before, after


@pytest.mark.parametrize("v0", [100.0, 37.3, 150.0])
def test_the_watchdog_trips_after_its_timeout_and_ramps_down_linearly(session, v0):
    """V0 is the DRIVE as it came over the wire (binary32); the ramp itself is computed in double."""
    before, after = trip(session, v0)
    v0 = f32(v0)
    assert voltages(before) == [v0] * WATCHDOG_TICKS
    assert all(not t.faults() and not t.measurement.status & TRIPPED for t in before)
    assert voltages(after) == close(ramp(v0)) and [t.measurement.drive_voltage for t in after] == close(ramp(v0))
    [fault] = after[0].faults()
    assert fault == Fault((1 + WATCHDOG_TICKS) * 1000, FaultCode.WATCHDOG, f32(WATCHDOG_TICKS * FAST.sample_period_s))
    assert all(t.measurement.status & TRIPPED and t.measurement.status & SESSION for t in after)
    assert sum(len(t.faults()) for t in after) == 1
    assert voltages(session.ticks(50)) == [0.0] * 50


def test_the_watchdog_trips_from_a_clamped_voltage(session):
    session.ticks(WATCHDOG_TICKS, Drive(400.0))
    after = session.ticks(RAMP_TICKS + 3)
    assert voltages(after) == close(ramp(150.0))


def test_a_tripped_watchdog_ignores_drive_until_hello(session):
    trip(session, 100.0)
    seq, frames_ok = session.firmware.command_seq, session.firmware.decoder.counters.frames_ok
    ignored = [session.tick(Drive(80.0)) for _ in range(5)]
    assert voltages(ignored) == [0.0] * 5 and all(t.measurement.status & TRIPPED for t in ignored)
    assert session.firmware.command_seq == seq and all(t.measurement.command_seq == seq for t in ignored)
    assert session.firmware.decoder.counters.frames_ok == frames_ok + 5  # counted though ignored


def test_hello_clears_the_trip_and_the_next_drive_drives_again(session):
    """Regression: after the HELLO the watchdog must wait for a DRIVE, not re-trip at once on the old one."""
    trip(session, 100.0)
    session.ticks(3)
    ack = session.hello()
    assert ack.of(HelloAck) and not ack.measurement.status & TRIPPED
    quiet = session.ticks(3 * WATCHDOG_TICKS)
    assert voltages(quiet) == [0.0] * len(quiet)
    assert all(not t.faults() and not t.measurement.status & TRIPPED for t in quiet)
    before, after = trip(session, 70.0)  # re-armed by the DRIVE, and it trips again on silence
    assert voltages(before) == [70.0] * WATCHDOG_TICKS and before[0].measurement.command_seq == 1
    assert voltages(after) == close(ramp(70.0)) and [len(t.faults(FaultCode.WATCHDOG)) for t in after[:2]] == [1, 0]


def test_hello_during_the_ramp_clears_the_trip_and_the_ramp_runs_on(session):
    trip_ticks = session.ticks(WATCHDOG_TICKS + 2, Drive(100.0))  # the trip, then one ramp step
    assert voltages(trip_ticks[-2:]) == close(ramp(100.0)[:2])
    ack = session.hello()
    rest = session.ticks(RAMP_TICKS)
    assert [ack.voltage, *voltages(rest)] == close(ramp(100.0)[2:2 + RAMP_TICKS + 1])
    assert not any(t.measurement.status & TRIPPED for t in [ack, *rest])


def test_host_heartbeats_do_not_feed_the_watchdog(session):
    session.tick(Drive(60.0))
    beats = [session.tick(HostHeartbeat()) for _ in range(WATCHDOG_TICKS)]
    assert voltages(beats) == [60.0] * WATCHDOG_TICKS and beats[-1].faults(FaultCode.WATCHDOG)
    assert voltages(session.ticks(2)) == [45.0, 30.0]


def test_a_hello_keeps_the_drive_in_force_and_the_watchdog_counting(session):
    """A host that reconnects within the watchdog time takes over without a bump."""
    session.ticks(2, Drive(80.0))  # DRIVE at tick 1
    reconnect = session.hello()  # tick 3
    assert reconnect.of(HelloAck) and reconnect.voltage == 80.0 and reconnect.measurement.command_seq == 1
    kept = session.ticks(WATCHDOG_TICKS - 3)  # ticks 4-5
    assert voltages(kept) == [80.0, 80.0] and not any(t.faults() for t in kept)
    tripped = session.tick()  # tick 6 = DRIVE + watchdog
    assert tripped.faults(FaultCode.WATCHDOG) and tripped.measurement.status & TRIPPED


def test_a_hello_then_drive_takes_over_without_a_trip(session):
    session.ticks(2, Drive(80.0))
    session.hello()
    taken_over = session.ticks(3 * WATCHDOG_TICKS, Drive(85.0))[:WATCHDOG_TICKS]
    assert voltages(taken_over) == [85.0] * WATCHDOG_TICKS and not any(t.faults() for t in taken_over)


# --- STOP ------------------------------------------------------------------------------------------

def test_stop_ends_the_session_and_ramps_down(session):
    session.ticks(2, Drive(100.0))
    stopped = session.ticks(3 * HEARTBEAT_TICKS, Stop())
    assert voltages(stopped[:RAMP_TICKS + 3]) == close(ramp(100.0))
    assert not session.firmware.session and not any(t.of(Measurement) for t in stopped)
    assert not any(t.faults() for t in stopped)  # disarmed: no watchdog trip
    beats = [beat for t in stopped for beat in t.of(RigHeartbeat)]
    assert beats and all(not beat.status & (SESSION | TRIPPED) for beat in beats)


def test_drive_and_stop_after_stop_are_ignored(session):
    session.ticks(2, Drive(100.0))
    session.tick(Stop())  # tick 3
    ramp_ticks = [session.tick(Drive(120.0)), session.tick(Stop()), *session.ticks(RAMP_TICKS)]
    assert voltages(ramp_ticks) == close(ramp(100.0)[1:RAMP_TICKS + 3])
    assert session.firmware.command_seq == 1 and not session.firmware.armed


def test_stop_keeps_a_trip_until_the_next_hello(session):
    trip(session, 100.0)
    session.tick(Stop())
    [beat] = [b for t in session.ticks(HEARTBEAT_TICKS) for b in t.of(RigHeartbeat)]
    assert beat.status & TRIPPED and not beat.status & SESSION
    assert not session.hello().measurement.status & TRIPPED


def test_stop_during_a_watchdog_ramp_lets_the_ramp_run_on(session):
    """STOP ramps down "exactly as the watchdog does": a ramp already running is not started over."""
    session.ticks(WATCHDOG_TICKS, Drive(100.0))
    during = [session.tick() for _ in range(3)] + [session.tick(Stop())] + session.ticks(RAMP_TICKS)
    assert voltages(during) == close(ramp(100.0, then=3))


def test_drive_after_stop_and_hello_drives_again(session):
    session.ticks(2, Drive(100.0))
    session.tick(Stop())
    session.hello()
    assert session.tick(Drive(20.0)).voltage == 20.0


# --- clamp -----------------------------------------------------------------------------------------

def test_drive_above_the_limit_is_clamped_with_one_fault_per_episode(session):
    commands = [200.0, 180.0, 150.0, 160.0, 160.0, 100.0, 151.0]
    ticks = [session.tick(Drive(v)) for v in commands]
    assert voltages(ticks) == [150.0, 150.0, 150.0, 150.0, 150.0, 100.0, 150.0]
    limited = [bool(t.measurement.status & LIMITED) for t in ticks]
    assert limited == [True, True, False, True, True, False, True]
    assert [[f.detail for f in t.faults(FaultCode.DRIVE_LIMITED)] for t in ticks] == [
        [200.0], [], [], [160.0], [], [], [151.0]]
    assert ticks[0].faults()[0].timestamp_us == 1000


def test_hello_clears_drive_limited_and_a_new_episode_faults_again(session):
    session.tick(Drive(200.0))
    ack = session.hello()
    assert not ack.measurement.status & LIMITED and ack.voltage == 150.0
    assert [f.detail for f in session.tick(Drive(300.0)).faults(FaultCode.DRIVE_LIMITED)] == [300.0]


# --- bad frames ------------------------------------------------------------------------------------

def damaged(frame: bytes) -> bytes:
    """``frame`` with one bit of its CRC flipped, stuffed again: it unstuffs, and fails the CRC check."""
    unstuffed = bytearray(cobs.decode(frame[:-1]))
    unstuffed[-1] ^= 0x10
    return cobs.encode(bytes(unstuffed)) + b"\x00"


def test_corrupt_frames_give_one_bad_frame_fault_per_tick_and_change_nothing(session):
    session.tick(Drive(50.0))
    bad = damaged(encode(Drive(120.0), 2)) + b"\x05\x01\x00" + damaged(encode(Stop(), 3))
    hit = session.tick(raw=bad)
    counters = session.firmware.decoder.counters
    assert counters.crc_errors == 2 and counters.cobs_errors + counters.truncated == 1 and counters.dropped == 3
    assert hit.faults() == [Fault(2000, FaultCode.BAD_FRAME, 3.0)]
    assert hit.voltage == 50.0 and session.firmware.session and hit.measurement.command_seq == 1
    assert not session.tick().faults()  # nothing new dropped: no fault
    assert session.tick(raw=damaged(encode(Drive(1.0), 9))).faults() == [Fault(4000, FaultCode.BAD_FRAME, 4.0)]
    [beat] = [b for t in session.ticks(HEARTBEAT_TICKS) for b in t.of(RigHeartbeat)]
    assert (beat.frames_received, beat.frames_dropped) == (2, 4)


def test_duplicates_are_dropped_and_gaps_counted_as_lost(session):
    """§3: a frame sent twice is used once (the copy is out_of_order: a BAD_FRAME fault); frames that never
    came are counted as lost when the next one is accepted, and are no fault."""
    frame = session.frame(Drive(40.0))  # seq 1
    hit = session.tick(raw=frame + frame)
    counters = session.firmware.decoder.counters
    assert hit.voltage == 40.0 and hit.measurement.command_seq == 1
    assert (counters.frames_ok, counters.out_of_order, counters.lost) == (2, 1, 0)
    assert hit.faults() == [Fault(1000, FaultCode.BAD_FRAME, 1.0)]
    old = session.tick(raw=encode(Drive(99.0), 0))  # older than the last accepted: dropped, changes nothing
    assert old.voltage == 40.0 and [f.detail for f in old.faults()] == [2.0]
    session.host.next_seq = 5  # seqs 2, 3 and 4 never sent (lost on the wire)
    gap = session.tick(Drive(45.0))
    counters = session.firmware.decoder.counters
    assert gap.voltage == 45.0 and gap.measurement.command_seq == 5 and not gap.faults()
    assert (counters.frames_ok, counters.out_of_order, counters.lost) == (3, 2, 3)


@pytest.mark.parametrize("voltage", [-1.0, -1e-30, math.nan, math.inf, -math.inf])
def test_an_invalid_drive_is_dropped_and_has_no_effect(session, voltage):
    session.tick(Drive(30.0))  # tick 1: armed, trips at tick 1 + watchdog
    session.tick()
    hit = session.tick(Drive(voltage))  # would feed the watchdog and change the voltage if used
    assert session.firmware.decoder.counters.invalid_value == 1
    assert hit.faults() == [Fault(3000, FaultCode.BAD_FRAME, 1.0)]
    assert hit.voltage == 30.0 and hit.measurement.command_seq == 1 and session.firmware.command_seq == 1
    rest = session.ticks(WATCHDOG_TICKS - 2)  # ticks 4..6: trips at tick 6 as if the frame never came
    assert voltages(rest) == [30.0] * (WATCHDOG_TICKS - 2) and rest[-1].faults(FaultCode.WATCHDOG)


def test_timing_below_two_sample_periods_is_rejected():
    with pytest.raises(InvalidParameterError, match="watchdog_timeout_s"):
        RigTiming(sample_period_s=1e-3, watchdog_timeout_s=1.5e-3)


def test_a_flood_of_host_bytes_in_one_tick_is_survived(session):
    """More bytes in one tick than a line carries (the C firmware's tunnel: 2048): the oldest are lost, as in a UART's
    overrun, and the session goes on: the second DRIVE after it is applied (the Cortex-M4F build's 256-byte queue loses
    the flood's last delimiter, and with it the first frame after it; a host's flood once ended the emulator)."""
    session.tick(raw=b"\x01" * 5000 + b"\x00")
    session.tick(Drive(42.5))
    driven = session.tick(Drive(42.5))
    assert driven.voltage == 42.5 and driven.measurement.drive_voltage == 42.5  # the session went on
    if isinstance(session.firmware, ExternalFirmware):
        assert session.firmware.host_bytes_dropped == 5001 - TUNNEL_BYTES
