"""The host's link to the rig (nfal.hil.link.RigLink), and the HardwareProxy slave over it, against a real rig
side on a pty.

The rig is a :class:`Firmware` ticked at 1 kHz by a background thread on a :class:`PtyPort` (receive,
voltage, report with a per-tick :class:`RigReading`, write through a :class:`FaultInjector`), so each
test runs the host's code path as it runs against the emulator. Every test is run with the link's reader
thread and with the owner polling (``reader_thread=False``, as the HardwareProxy does).
"""

from __future__ import annotations

import dataclasses
import struct
import threading
import time
from collections.abc import Callable

import pytest

from nfal.errors import InvalidParameterError, LinkError
from nfal.hil import link as link_module
from nfal.hil.faults import FaultInjector, FaultSettings
from nfal.hil.firmware import Firmware, RigReading, RigTiming
from nfal.hil.link import LinkCounters, RigLink
from nfal.hil.ports import PtyPort
from nfal.hil.protocol import (HOST_TO_RIG, PROTOCOL_VERSION, DecoderCounters, FaultCode, FrameDecoder, Hello, HelloAck,
                               Measurement, StatusFlags)

pytestmark = pytest.mark.realtime  # on the wall clock: one at a time, on one worker (conftest.py)

#: 1 kHz rig; a long watchdog so that a busy machine never trips it in a test that drives.
TIMING = RigTiming(sample_period_s=1e-3, watchdog_timeout_s=0.5, ramp_down_s=0.05, max_drive_voltage=150.0,
                   heartbeat_period_s=0.02)
ACK = HelloAck(1, 1000, 500_000, 50_000, 150.0)
#: Generous bound on waits for something the rig does within a few ms [s].
WAIT_S = 3.0

def f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]

def height_at(tick: int) -> float:
    """The rig's measured height at ``tick``: different every tick, so a damaged frame cannot pass as another."""
    return 1e-4 + (tick % 100_000) * 1e-10


class FakeRig:
    """A :class:`Firmware` on a :class:`PtyPort`, ticked by a thread at ``timing.sample_period_s``.

    Port and firmware are used under :attr:`lock`, so the test may disconnect the port or look at the firmware
    between ticks. ``inject`` may be swapped in (fault injection on what the rig sends).
    """

    def __init__(self, path, timing: RigTiming = TIMING) -> None:
        self.timing = timing
        self.port = PtyPort(path)
        self.firmware = Firmware(timing)
        self.inject = FaultInjector(FaultSettings())
        self.lock = threading.Lock()
        self.sent: dict[int, Measurement] = {}  # timestamp_us -> the MEASUREMENT the rig sent
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="fake rig", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return str(self.port.path)

    def _run(self) -> None:
        period, k = self.timing.sample_period_s, 0
        start = time.perf_counter()
        while not self._stop.is_set():
            with self.lock:
                firmware = self.firmware
                out = firmware.receive(self.port.read(), k)
                _, faults = firmware.voltage(k)
                out += faults
                out += firmware.report(k, RigReading(height_at(k), 28_500.0, True, False))
                if firmware.session:
                    self.sent[firmware.last_measurement.timestamp_us] = firmware.last_measurement
                frames = self.inject(out, k * period)
                if frames:
                    self.port.write(b"".join(frames))
            k += 1
            delay = start + k * period - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            elif delay < -0.05:  # stalled (a busy machine): go on from now, like the emulator
                start = time.perf_counter() - k * period

    def state(self) -> tuple[bool, float, int]:
        """(session open, applied voltage, command_seq), between two ticks."""
        with self.lock:
            return self.firmware.session, self.firmware.applied, self.firmware.command_seq

    def disconnect(self) -> None:
        with self.lock:
            self.port.disconnect()

    def connect(self) -> None:
        with self.lock:
            self.port.connect()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.port.close()


@pytest.fixture
def rig(tmp_path):
    started: list[FakeRig] = []

    def start(timing: RigTiming = TIMING) -> FakeRig:
        started.append(FakeRig(tmp_path / f"rig{len(started)}", timing))
        return started[-1]

    yield start
    for fake in started:
        fake.stop()


@pytest.fixture(params=[True, False], ids=["reader thread", "owner polls"])
def links(request):
    """Makes RigLinks with and without a reader thread; closes them all afterwards."""
    made: list[RigLink] = []

    def make(url: str, **options) -> RigLink:
        made.append(RigLink(url, reader_thread=request.param, **options))
        return made[-1]

    yield make
    for link in made:
        link.close()

def wait_for(link: RigLink, condition: Callable[[], bool], timeout_s: float = WAIT_S) -> bool:
    """Poll (if the link has no reader thread) until ``condition()`` or the timeout; returns the last value."""
    return link.wait_until(condition, timeout_s)

def keep_polling(link: RigLink, seconds: float) -> None:
    """Let ``seconds`` pass with the link taking in what comes (polling it, if it has no reader thread)."""
    wait_for(link, lambda: False, timeout_s=seconds)

def count(link: RigLink) -> int:
    sample = link.latest()
    return 0 if sample is None else sample.count


# --- session ---------------------------------------------------------------------------------------


def test_open_returns_the_rigs_hello_ack_and_measurements_arrive(rig, links):
    fake = rig()
    link = links(fake.url)
    assert link.open() == ACK == link.rig and link.connected
    assert wait_for(link, lambda: count(link) >= 20)
    seqs, heights = [], []
    for _ in range(5):
        first = link.latest().count
        assert wait_for(link, lambda: link.latest().count > first)
        sample = link.latest()
        seqs.append(sample.seq)
        heights.append((sample.measurement.timestamp_us, sample.measurement.height))
    assert seqs == sorted(set(seqs))
    for timestamp_us, height in heights:  # the exact height the rig measured at that tick, as binary32
        assert height == f32(height_at(timestamp_us // 1000)) == f32(fake.sent[timestamp_us].height)
    measurement = link.latest().measurement
    assert measurement.status & StatusFlags.SESSION_ACTIVE and measurement.status & StatusFlags.PLL_LOCKED
    assert measurement.drive_frequency == 28_500.0 and measurement.drive_voltage == 0.0
    assert link.counters.measurements >= 25 and link.decoder.counters.dropped == 0


def test_send_drive_reaches_the_firmware(rig, links):
    fake = rig()
    link = links(fake.url)
    link.open()
    assert link.send_drive(42.5) and link.counters.drives_sent == 1
    assert wait_for(link, lambda: fake.state()[2] == 1)  # HELLO is seq 0, this DRIVE seq 1
    assert fake.state() == (True, 42.5, 1)
    assert wait_for(link, lambda: link.latest() is not None and link.latest().measurement.command_seq == 1)
    assert link.latest().measurement.drive_voltage == 42.5
    assert link.send_drive(7) and wait_for(link, lambda: fake.state() == (True, 7.0, 2))


def test_close_sends_stop_and_is_idempotent(rig, links):
    fake = rig()
    link = links(fake.url)
    link.open()
    link.send_drive(30.0)
    assert wait_for(link, lambda: fake.state()[2] == 1)
    link.close()
    assert not link.connected
    assert wait_for(link, lambda: not fake.state()[0], timeout_s=1.0)  # the firmware's session ended
    link.close()
    link.close(stop=False)
    assert not link.send_drive(1.0) and (link.counters.drives_sent, link.counters.drives_not_sent) == (1, 1)


def test_health_has_every_counter(rig, links):
    fake = rig()
    link = links(fake.url)
    link.open()
    assert wait_for(link, lambda: link.counters.heartbeats >= 2)
    health = link.health()
    names = {f.name for f in dataclasses.fields(LinkCounters)} | {f.name for f in dataclasses.fields(DecoderCounters)}
    assert set(health) == names | {"dropped", "rig_frames_dropped", "connected", "last_error", "drive_gaps"}
    assert health["connected"] is True and health["last_error"] == "" and health["heartbeats"] >= 2
    assert health["frames_ok"] >= health["measurements"] + health["heartbeats"] and health["dropped"] == 0
    link.close()
    assert link.health()["connected"] is False


def test_a_second_open_is_refused(rig, links):
    link = links(rig().url)
    link.open()
    with pytest.raises(LinkError, match="already open"):
        link.open()


def test_a_second_host_on_the_same_port_is_refused_and_the_first_keeps_its_session(rig, links):
    fake = rig()
    first = links(fake.url)
    first.open()
    second = RigLink(fake.url, connect_timeout_s=0.5, reader_thread=False)
    with pytest.raises(LinkError, match="in use by another program.*one host per rig"):
        second.open()
    assert first.send_drive(3.0) and wait_for(first, lambda: fake.state() == (True, 3.0, 1))
    first.close()
    second.open()  # free again once the first host has closed it
    second.close()


def test_the_gaps_between_drive_commands_are_measured(rig, links):
    link = links(rig().url)
    link.open()
    for _ in range(5):
        link.send_drive(1.0)
        time.sleep(0.002)
    gaps = link.health()["drive_gaps"]
    assert gaps["count"] == 4 and 0.002 <= gaps["p50_s"] <= gaps["max_s"]


@pytest.mark.parametrize("name, value", [("connect_timeout_s", 1e9), ("reconnect_interval_s", 3600.0),
                                         ("connect_timeout_s", 0.0)])
def test_every_wait_of_the_link_is_bounded(name, value):
    with pytest.raises(InvalidParameterError, match=f"{name}.*at most 60 s"):
        RigLink("loop://", **{name: value})


# --- failures to connect -----------------------------------------------------------------------------


def test_a_port_where_nothing_answers_fails_within_the_connect_timeout(tmp_path, links):
    silent = PtyPort(tmp_path / "silent")  # a pty with no firmware behind it
    try:
        link = links(str(silent.path), connect_timeout_s=0.3)
        started = time.monotonic()
        with pytest.raises(LinkError, match="HELLO_ACK") as failure:
            link.open()
        elapsed = time.monotonic() - started
        assert str(silent.path) in str(failure.value)
        assert 0.3 <= elapsed < 3.0  # measured: 0.30-0.31 s idle; > 1 s seen with both cores busy
        assert link.counters.handshake_failures >= 1 and not link.connected
        # the HELLO went out and waited in the pty; on a busy machine, where the timeout comes late, with its repeats
        # (spec 6), and the HELLO of a reader thread's reconnection after a failed handshake (a loaded CI run: 2 HELLOs,
        # no repeat)
        hellos = FrameDecoder(HOST_TO_RIG).feed(silent.read())
        assert 1 <= len(hellos) <= 1 + link.counters.hellos_repeated + link.counters.handshake_failures
        assert all(hello.message == Hello(PROTOCOL_VERSION) and hello.seq == 0 for hello in hellos)
    finally:
        silent.close()


@pytest.mark.parametrize("url", ["", "   "])
def test_an_empty_url_is_refused(url):
    with pytest.raises(LinkError, match="no port given"):
        RigLink(url)


def test_a_path_that_does_not_exist_cannot_be_opened(tmp_path, links):
    link = links(str(tmp_path / "no-such-port"), connect_timeout_s=0.3)
    with pytest.raises(LinkError, match="cannot open") as failure:
        link.open()
    assert "no-such-port" in str(failure.value) and not link.connected


@pytest.mark.parametrize("side", ["host", "rig"])


def test_a_rig_that_refuses_the_version_fails_naming_it(rig, links, monkeypatch, side):
    """The host asks for version 2 (its PROTOCOL_VERSION patched), or the rig speaks only version 2."""
    fake = rig()
    if side == "host":
        monkeypatch.setattr(link_module, "PROTOCOL_VERSION", 2)
        asked = 2
    else:
        monkeypatch.setattr("nfal.hil.firmware.PROTOCOL_VERSION", 2)
        asked = 1
    link = links(fake.url, connect_timeout_s=0.3, reconnect=False)
    with pytest.raises(LinkError, match=rf"refused protocol version {asked}\b.*VERSION_MISMATCH.*detail {asked}\b"):
        link.open()
    assert link.counters.handshake_failures >= 1 and not link.connected
    assert link.faults and {f.code for f in link.faults} == {FaultCode.VERSION_MISMATCH}
    assert {f.detail for f in link.faults} == {asked} and not fake.state()[0]


def test_a_refusal_is_reported_even_if_the_reader_reconnects_during_open(rig, monkeypatch):
    monkeypatch.setattr("nfal.hil.firmware.PROTOCOL_VERSION", 2)
    fake = rig()
    answered: list[bytes] = []
    receive = fake.firmware.receive

    def receive_once(data: bytes, tick: int) -> list[bytes]:
        out = receive(data, tick)
        if answered:
            return []  # busy after its first answer
        answered.extend(out)
        return out

    with fake.lock:
        fake.firmware.receive = receive_once
    calls = []

    def clock() -> float:  # the first call stamps the HELLO; after it, the reader's deadline comes at 0.25 s
        calls.append(None)
        return time.perf_counter() + (0.25 if len(calls) > 1 else 0.0)

    link = RigLink(fake.url, connect_timeout_s=0.5, clock=clock)  # open() waits 0.5 s of wall time
    try:
        with pytest.raises(LinkError, match="refused protocol version 1"):
            link.open()
    finally:
        link.close()
    assert answered  # the rig did refuse


def test_a_loop_url_gets_as_far_as_waiting_for_the_hello_ack(links):
    """loop:// echoes the HELLO (the host drops it: a host -> rig type), and nothing answers."""
    link = links("loop://", connect_timeout_s=0.2)
    with pytest.raises(LinkError, match="HELLO_ACK"):
        link.open()


# --- disconnection -----------------------------------------------------------------------------------


def test_a_disconnect_is_counted_and_the_link_reconnects(rig, links):
    fake = rig()
    link = links(fake.url, reconnect_interval_s=0.02)
    link.open()
    assert wait_for(link, lambda: count(link) >= 10)
    fake.disconnect()
    assert wait_for(link, lambda: link.counters.disconnects == 1)
    assert not link.connected and link.last_error  # why: the read failed, then the reopening did
    assert "failed" in link.last_error or "cannot open" in link.last_error
    keep_polling(link, 0.2)  # reopening fails meanwhile (the path is gone); that is no new disconnect
    assert link.counters.disconnects == 1 and not link.connected and "cannot open" in link.last_error
    before = count(link)
    fake.connect()
    assert wait_for(link, lambda: link.connected and count(link) > before + 10)
    assert (link.counters.disconnects, link.counters.reconnects) == (1, 1)
    assert link.latest().measurement.status & StatusFlags.SESSION_ACTIVE
    assert link.send_drive(12.0) and wait_for(link, lambda: fake.state()[1] == 12.0)


def test_the_reason_for_a_disconnect_is_kept(rig, links):
    fake = rig()
    link = links(fake.url, reconnect=False)
    link.open()
    assert wait_for(link, lambda: count(link) >= 5)
    fake.disconnect()
    assert wait_for(link, lambda: link.counters.disconnects == 1)
    assert link.last_error.startswith(("read failed", "write failed"))
    assert link.health()["last_error"] == link.last_error


def test_without_reconnect_the_link_stays_down(rig, links):
    fake = rig()
    link = links(fake.url, reconnect=False, reconnect_interval_s=0.02)
    link.open()
    assert wait_for(link, lambda: count(link) >= 5)
    fake.disconnect()
    assert wait_for(link, lambda: link.counters.disconnects == 1)
    fake.connect()
    stuck = count(link)
    assert not wait_for(link, lambda: link.connected or count(link) > stuck, timeout_s=0.3)
    assert (link.counters.disconnects, link.counters.reconnects) == (1, 0) and not link.send_drive(1.0)


# --- damaged frames ----------------------------------------------------------------------------------


def test_corrupted_frames_are_counted_and_never_used(rig, links):
    """20 % of the rig's frames get one bit flipped (after the handshake). Every MEASUREMENT the host accepts
    is one the rig sent, bit for bit; the damaged ones are in the decoder's counters."""
    fake = rig()
    link = links(fake.url)
    link.open()
    with fake.lock:
        fake.inject = FaultInjector(FaultSettings(corrupt=0.2, seed=5))
    accepted: list[Measurement] = []
    feed = link.decoder.feed

    def recording_feed(data):
        received = feed(data)
        accepted.extend(r.message for r in received if isinstance(r.message, Measurement))
        return received

    link.decoder.feed = recording_feed
    assert wait_for(link, lambda: fake.inject.counts.corrupted >= 60)
    with fake.lock:
        corrupted, fake.inject = fake.inject.counts.corrupted, FaultInjector(FaultSettings())
    after = count(link)
    assert wait_for(link, lambda: count(link) > after + 20)  # frames come in order: every damaged one is in
    counters = link.decoder.counters
    damage = counters.crc_errors + counters.cobs_errors + counters.truncated + counters.oversized
    assert damage >= corrupted >= 60  # a bit flipped to 0x00 splits a frame into two drops
    assert counters.lost > 0 and counters.invalid_value == 0 and counters.unknown_type == 0
    assert len(accepted) > 100
    for measurement in accepted:
        sent = fake.sent[measurement.timestamp_us]
        assert measurement.height == f32(sent.height) == f32(height_at(measurement.timestamp_us // 1000))
        assert (measurement.drive_frequency, measurement.drive_voltage, measurement.status, measurement.command_seq) \
            == (sent.drive_frequency, sent.drive_voltage, sent.status, sent.command_seq)


def test_a_partial_frame_left_in_the_rig_does_not_spoil_the_hello(rig, links):
    fake = rig()
    with fake.lock:
        fake.firmware.receive(b"\x03\x02\x07\x01", 0)  # the start of a DRIVE frame, the rest never came
    link = links(fake.url, connect_timeout_s=0.3, reconnect=False)
    assert link.open() == ACK


# --- a backlog, a session before ours, a port slow to open ---------------------------------------------


def test_a_poll_after_a_stall_drains_the_backlog_so_the_newest_sample_is_the_newest_sent(rig):
    """An owner that polls (the reader thread never lets a backlog build up): 250 frames without a poll (9 kB, over two
    READ_CHUNKs; a pty holds 12-20 kB) wait in the port, and one poll takes them all."""
    fake = rig()
    link = RigLink(fake.url, reader_thread=False)
    link.open()
    sent = len(fake.sent)
    while len(fake.sent) < sent + 250:  # counted in the rig's frames, not the wall clock: a busy machine slows both
        time.sleep(0.005)
    with fake.lock:  # the rig stops between two ticks: what it has sent is all in the port
        newest_sent = max(fake.sent)
        link.poll()
    link.close()
    assert fake.port.bytes_dropped == 0  # the pty had room for all of it
    assert link.latest().measurement.timestamp_us == newest_sent
    assert link.counters.measurements >= 200 and link.decoder.counters.dropped == 0


def _rig_on_a_socket(*bursts: bytes, hellos: int = 1):
    """A server on loopback that answers the host's ``hellos``-th HELLO with ``bursts``, 50 ms apart (the HELLOs before
    it get no answer, as if lost on the wire): (url, thread, the socket server)."""
    import socket

    server = socket.create_server(("127.0.0.1", 0))

    def serve() -> None:
        peer, _ = server.accept()
        with peer:
            peer.settimeout(WAIT_S)
            received = b""
            while sum(isinstance(r.message, Hello) for r in FrameDecoder(HOST_TO_RIG).feed(received)) < hellos:
                received += peer.recv(64)
            for burst in bursts:
                peer.sendall(burst)
                time.sleep(0.05)
            time.sleep(0.5)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    return f"socket://127.0.0.1:{server.getsockname()[1]}", thread, server


def test_measurements_before_our_hello_ack_belong_to_the_session_before_and_are_not_taken(links):
    """A rig still streaming to a host that went away (or whose HELLO is in flight after a reconnection) sends
    MEASUREMENTs before it answers our HELLO: they are counted, never used."""
    from nfal.hil.protocol import FrameEncoder

    encoder = FrameEncoder()
    old = encoder(Measurement(1_000, 150e-6, 28_500.0, 40.0, int(StatusFlags.WATCHDOG_TRIPPED), 3))
    encoder.restart()
    frames = [old, encoder(ACK), encoder(Measurement(2_000, 100e-6, 28_500.0, 0.0, 0, 0))]
    url, thread, server = _rig_on_a_socket(b"".join(frames))
    with server:
        link = links(url, connect_timeout_s=WAIT_S)
        assert link.open() == ACK
        assert wait_for(link, lambda: link.latest() is not None)
        assert link.latest().measurement.timestamp_us == 2_000 and link.latest().measurement.status == 0
        assert link.counters.measurements == 1 and link.counters.measurements_before_session == 1
        thread.join(timeout=WAIT_S)


def test_a_hello_without_an_answer_is_said_again(links):
    """A HELLO or its HELLO_ACK lost on the wire (a noisy line, the emulator's --drop): the host says HELLO again
    after HELLO_REPEAT_S instead of waiting out the connect timeout."""
    from nfal.hil.protocol import FrameEncoder

    url, thread, server = _rig_on_a_socket(FrameEncoder()(ACK), hellos=2)
    with server:
        link = links(url, connect_timeout_s=WAIT_S)
        started = time.monotonic()
        assert link.open() == ACK
        assert link_module.HELLO_REPEAT_S <= time.monotonic() - started < WAIT_S
        assert link.counters.hellos_repeated == 1 and link.counters.handshake_failures == 0
        thread.join(timeout=WAIT_S)


def test_a_late_answer_then_a_lost_one_does_not_look_like_a_restart(links):
    """The answer to HELLO comes late (after the host repeated HELLO), the rig answers the repeat too, restarting its
    count, and that second HELLO_ACK is lost: the host follows the new count at once, without a new session."""
    from nfal.hil.protocol import FrameEncoder

    encoder = FrameEncoder()

    def measurements(first_seq: int, n: int, t0_us: int) -> bytes:
        encoder.next_seq = first_seq
        return b"".join(encoder(Measurement(t0_us + 1000 * k, 1e-4, 28_500.0, 0.0, 2, 0)) for k in range(n))

    encoder.restart()
    url, thread, server = _rig_on_a_socket(
        encoder(ACK) + measurements(1, 10, 0),  # the late answer to the first HELLO, then seq 1-10
        measurements(1, 3, 20_000),  # counting from 0 again: its HELLO_ACK (seq 0) was lost
        measurements(4, 5, 23_000), hellos=2)
    with server:
        link = links(url, connect_timeout_s=WAIT_S)
        assert link.open() == ACK and link.counters.hellos_repeated == 1
        # the last frame the rig sent, 0.1 s after the first: before RESTART_SILENCE_S could pass
        assert wait_for(link, lambda: link.latest() is not None and link.latest().measurement.timestamp_us == 27_000,
                        timeout_s=0.4)
        assert link.counters.rig_restarts == 0 and link.decoder.counters.out_of_order >= 1
        thread.join(timeout=WAIT_S)


def test_a_rig_that_restarts_gets_a_new_hello(rig, links):
    """A rebooted rig counts from 0 again and sends only heartbeats (no session): every frame looks old to the host
    (spec 3), which says HELLO again after RESTART_SILENCE_S, and the measurements resume."""
    fake = rig()
    link = links(fake.url)
    link.open()
    assert wait_for(link, lambda: count(link) >= 200)  # seqs well past what the restarted rig will send
    with fake.lock:
        fake.firmware = Firmware(TIMING)
    before = count(link)
    assert wait_for(link, lambda: link.counters.rig_restarts == 1 and count(link) > before + 10)
    assert link.decoder.counters.out_of_order >= 3 and link.counters.reconnects == 1 and link.connected
    assert fake.state()[0]  # the restarted firmware has a session


def test_an_owner_that_polls_never_waits_for_the_port_to_reopen(rig, monkeypatch):
    """Reopening a socket:// port can take seconds: a helper thread opens it, and every poll returns at once."""
    fake = rig()
    link = RigLink(fake.url, reader_thread=False, reconnect_interval_s=0.01)
    try:
        link.open()
        open_port = link_module.serial.serial_for_url

        def slow_open(*args, **kwargs):
            time.sleep(0.3)
            return open_port(*args, **kwargs)

        monkeypatch.setattr(link_module.serial, "serial_for_url", slow_open)
        fake.disconnect()
        assert wait_for(link, lambda: link.counters.disconnects == 1)
        fake.connect()
        longest, deadline = 0.0, time.monotonic() + WAIT_S
        while not link.connected and time.monotonic() < deadline:
            started = time.perf_counter()
            link.poll()
            longest = max(longest, time.perf_counter() - started)
            time.sleep(0.001)
        assert link.connected and link.counters.reconnects == 1
        assert longest < 0.1  # measured: well under 1 ms; the open takes 0.3 s
    finally:
        link.close()


def test_a_port_opened_after_close_is_closed_at_once(rig, monkeypatch):
    fake = rig()
    link = RigLink(fake.url, reader_thread=False, reconnect_interval_s=0.01)
    opened, release = [], threading.Event()
    open_port = link_module.serial.serial_for_url

    def held_open(*args, **kwargs):
        release.wait(WAIT_S)
        opened.append(open_port(*args, **kwargs))
        return opened[-1]

    link.open()
    monkeypatch.setattr(link_module.serial, "serial_for_url", held_open)
    fake.disconnect()
    fake.connect()
    assert wait_for(link, lambda: link._opening is not None)
    link.close()
    release.set()
    assert wait_for_rig(lambda: bool(opened) and not opened[0].is_open, timeout_s=1.0)
    keep_polling(link, 0.05)
    assert not link.connected and link.counters.reconnects == 0


# --- the HardwareProxy slave over the link ----------------------------------------------------------


@pytest.fixture
def proxy():
    from nfal.fmus.hardware_proxy import HardwareProxy

    made = []

    def make(port: str, **parameters) -> HardwareProxy:
        slave = HardwareProxy(instance_name="proxy")
        slave.port, slave.sample_rate = port, 1 / TIMING.sample_period_s
        for name, value in parameters.items():
            setattr(slave, name, value)
        slave.setup_experiment(0.0)
        slave.exit_initialization_mode()
        made.append(slave)
        return slave

    yield make
    for slave in made:
        slave.terminate()


def test_the_proxy_fmu_validates_and_declares_its_contract(tmp_path):
    """fmpy.validation finds no problem; the variables of docs/hil.md's table, with their causalities and units."""
    from fmpy import read_model_description
    from fmpy.validation import validate_fmu

    from nfal.fmus.build import build_fmus

    fmu = str(build_fmus(tmp_path, ["HardwareProxy"])["HardwareProxy"])
    assert validate_fmu(fmu) == []
    variables = {v.name: (v.causality, v.type, v.unit) for v in read_model_description(fmu).modelVariables}
    assert variables["drive_voltage"] == ("input", "Real", "V")
    for name, unit in (("measured_height", "m"), ("drive_frequency", "Hz"), ("applied_voltage", "V"), ("rig_time", "s"),
                       ("measurement_age", "s")):
        assert variables[name] == ("output", "Real", unit)
    for name in ("locked", "resting", "watchdog_tripped", "sensor_out_of_range", "fresh", "link_ok"):
        assert variables[name][:2] == ("output", "Boolean")
    for name in ("samples_missed", "frames_dropped", "frames_lost", "rig_faults", "reconnects"):
        assert variables[name][:2] == ("output", "Integer")
    for name in ("port", "baud_rate", "connect_timeout", "max_missed_samples", "reconnect", "sample_rate"):
        assert variables[name][0] == "parameter"
    assert not read_model_description(fmu).coSimulation.canGetAndSetFMUstate  # the rig cannot be rewound


def test_the_proxy_starts_from_a_measured_sample_and_drives_the_rig(rig, proxy):
    fake = rig()
    slave = proxy(fake.url)
    assert slave.link_ok and slave.fresh and slave.measured_height > 0
    slave.drive_voltage = 30.0
    t = 0.0
    for _ in range(20):
        slave.do_step(t, 1e-3)
        t += 1e-3
        time.sleep(1e-3)
    assert fake.state()[1] == 30.0 and slave.applied_voltage == 30.0 and not slave.watchdog_tripped


def test_the_proxy_fails_when_the_rigs_watchdog_trips(rig, proxy):
    """A host that stalls past the rig's watchdog has lost control of the rig: the step says so, it does not go
    on with an open loop."""
    fake = rig(dataclasses.replace(TIMING, watchdog_timeout_s=0.02))
    slave = proxy(fake.url)
    slave.drive_voltage = 30.0
    slave.do_step(0.0, 1e-3)
    time.sleep(0.1)  # the host stalls: 100 ms without DRIVE
    with pytest.raises(LinkError, match="watchdog has tripped") as failure:
        slave.do_step(1e-3, 1e-3)
    assert "the loop is open" in str(failure.value) and not slave.link_ok
    assert wait_for_rig(lambda: fake.state()[1] == 0.0)  # the rig ramped the drive down (50 ms)


def wait_for_rig(condition: Callable[[], bool], timeout_s: float = WAIT_S) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.005)
    return True


def test_the_proxy_passes_on_the_rigs_status_flags(proxy):
    from nfal.hil.protocol import FrameEncoder

    encoder = FrameEncoder()
    flags = StatusFlags.SESSION_ACTIVE | StatusFlags.SENSOR_OUT_OF_RANGE | StatusFlags.RESTING
    url, thread, server = _rig_on_a_socket(encoder(ACK)
                                           + encoder(Measurement(5_000, 2e-3, 28_490.0, 12.0, int(flags), 0)))
    with server:
        slave = proxy(url)
        assert (slave.sensor_out_of_range, slave.resting, slave.locked, slave.watchdog_tripped) == \
            (True, True, False, False)
        assert (slave.measured_height, slave.drive_frequency, slave.applied_voltage, slave.rig_time) == \
            (f32(2e-3), 28_490.0, 12.0, 0.005)
        thread.join(timeout=WAIT_S)
