"""The emulator's fault injection (nfal.hil.faults) and its ports (nfal.hil.ports: a pty, any pyserial URL)."""

from __future__ import annotations

import math
import time

import pytest
import serial
from helpers.rig import StillRig

from nfal.errors import InvalidParameterError, LinkError
from nfal.hil.faults import FaultInjector, FaultSettings
from nfal.hil.ports import PtyPort, UrlPort
from nfal.hil.protocol import RIG_TO_HOST, FrameDecoder, FrameEncoder, Measurement, Received

pytestmark = pytest.mark.realtime  # on the wall clock: one at a time, on one worker (conftest.py)


def measurements(n: int) -> tuple[list[Measurement], list[bytes]]:
    """``n`` MEASUREMENTs (every field different per frame; reals as binary32, as they come off the wire) and
    their frames, seq 0 .. n - 1."""
    encoder = FrameEncoder()
    frames = [encoder(Measurement(k * 500, 1e-4 + k * 1e-9, 28_500.0 + k, 50.0 + k / 8, 3, k)) for k in range(n)]
    messages = [received.message for received in FrameDecoder(RIG_TO_HOST).feed(b"".join(frames))]
    assert len(messages) == n
    return messages, frames


MESSAGES, FRAMES = measurements(400)


# --- FaultInjector ---------------------------------------------------------------------------------


@pytest.mark.parametrize("settings", [
    FaultSettings(drop=0.3, seed=7), FaultSettings(corrupt=0.3, seed=7), FaultSettings(duplicate=0.3, seed=7),
    FaultSettings(drop=0.1, corrupt=0.1, duplicate=0.1, seed=7),
], ids=["drop", "corrupt", "duplicate", "all"])


def test_the_injector_is_seeded_and_reproducible(settings):
    first, second = FaultInjector(settings), FaultInjector(settings)
    out = first(FRAMES, 0.0)
    assert second(FRAMES, 0.0) == out and second.counts == first.counts and out != FRAMES
    other = FaultInjector(FaultSettings(**{**vars(settings), "seed": 8}))
    assert other(FRAMES, 0.0) != out


def test_zero_rates_pass_frames_unchanged():
    injector = FaultInjector(FaultSettings(seed=3))
    assert not injector.settings.active
    assert injector(FRAMES, 0.0) == FRAMES and injector(FRAMES[:5], 1.0) == FRAMES[:5]
    assert vars(injector.counts) == {"dropped": 0, "corrupted": 0, "duplicated": 0}


def test_drop_1_drops_every_frame():
    injector = FaultInjector(FaultSettings(drop=1.0))
    assert injector(FRAMES, 0.0) == [] and injector.counts.dropped == len(FRAMES)


def test_duplicate_1_doubles_every_frame():
    injector = FaultInjector(FaultSettings(duplicate=1.0))
    assert injector(FRAMES, 0.0) == [f for frame in FRAMES for f in (frame, frame)]
    assert injector.counts.duplicated == len(FRAMES)
    decoder = FrameDecoder(RIG_TO_HOST)
    assert [r.message for r in decoder.feed(b"".join(injector(FRAMES[:10], 0.0)))] == MESSAGES[:10]
    assert decoder.counters.out_of_order == 10


def test_corrupt_1_flips_exactly_one_bit_of_a_non_delimiter_byte_per_frame():
    injector = FaultInjector(FaultSettings(corrupt=1.0, seed=11))
    out = injector(FRAMES, 0.0)
    assert len(out) == len(FRAMES) == injector.counts.corrupted
    for original, damaged in zip(FRAMES, out):
        assert len(damaged) == len(original) and damaged[-1] == 0
        flipped = [(i, a ^ b) for i, (a, b) in enumerate(zip(original, damaged)) if a != b]
        assert len(flipped) == 1 and flipped[0][0] < len(original) - 1 and bin(flipped[0][1]).count("1") == 1
    decoder = FrameDecoder(RIG_TO_HOST)
    assert decoder.feed(b"".join(out)) == []
    counters = decoder.counters
    assert counters.frames_ok == 0 and counters.dropped >= len(FRAMES)  # a new 0x00 splits a frame in two drops
    assert counters.crc_errors + counters.cobs_errors > 0.9 * len(FRAMES)


@pytest.mark.parametrize("seed", [0, 1, 2])


def test_the_host_decodes_exactly_the_frames_that_were_not_corrupted(seed):
    injector = FaultInjector(FaultSettings(corrupt=0.3, seed=seed))
    out = injector(FRAMES, 0.0)
    intact = [Received(seq, message) for seq, (message, frame, sent) in enumerate(zip(MESSAGES, FRAMES, out))
              if frame == sent]
    decoder = FrameDecoder(RIG_TO_HOST)
    assert decoder.feed(b"".join(out)) == intact
    assert len(FRAMES) - len(intact) == injector.counts.corrupted > 0
    assert decoder.counters.dropped >= injector.counts.corrupted


def test_delay_holds_frames_until_due_in_order():
    """Times and the delay are binary fractions, so the release comparisons are exact."""
    injector = FaultInjector(FaultSettings(delay_s=0.25))
    a, b, c = FRAMES[:3]
    assert injector([a], 0.0) == []
    assert injector([b], 0.125) == []
    assert injector([], 0.2499) == []
    assert injector([c], 0.25) == [a]  # t + delay is due when now >= it
    assert injector([], 0.5) == [b, c]
    assert injector([], 10.0) == []


def test_delay_applies_after_the_other_faults():
    injector = FaultInjector(FaultSettings(duplicate=1.0, delay_s=0.5))
    assert injector(FRAMES[:2], 0.0) == [] and injector([], 0.5) == [FRAMES[0]] * 2 + [FRAMES[1]] * 2


@pytest.mark.parametrize("field, value", [
    ("drop", -0.1), ("drop", 1.5), ("corrupt", math.nan), ("corrupt", -1e-9), ("duplicate", 2.0),
    ("delay_s", -0.001), ("delay_s", 10.5), ("delay_s", math.nan), ("delay_s", math.inf),
])


def test_fault_settings_reject_bad_rates_and_delays(field, value):
    with pytest.raises(InvalidParameterError, match=field):
        FaultSettings(**{field: value})


@pytest.mark.parametrize("field, value", [("drop", 0.0), ("drop", 1.0), ("corrupt", 0.5), ("delay_s", 0.0),
                                          ("delay_s", 10.0)])


def test_fault_settings_accept_the_bounds(field, value):
    assert FaultSettings(**{field: value}).active == bool(value)


# --- PtyPort -----------------------------------------------------------------------------------------

def read_until(read, n: int, timeout_s: float = 2.0) -> bytes:
    """Read from a non-blocking ``read()`` until ``n`` bytes came (or the timeout)."""
    data, deadline = b"", time.monotonic() + timeout_s
    while len(data) < n and time.monotonic() < deadline:
        data += read() or b""
        if len(data) < n:
            time.sleep(0.001)
    return data


@pytest.fixture
def pty(tmp_path):
    port = PtyPort(tmp_path / "rig")
    yield port
    port.close()


@pytest.fixture
def client():
    """Opens pyserial clients at a path; closes them all afterwards."""
    opened = []

    def open_at(path) -> serial.SerialBase:
        opened.append(serial.serial_for_url(str(path), timeout=0.5))
        return opened[-1]

    yield open_at
    for handle in opened:
        handle.close()


def test_a_pty_client_exchanges_bytes_both_ways(pty, client):
    assert pty.connected and pty.path.is_symlink()
    host = client(pty.path)
    payload = bytes(range(256)) * 4  # every byte value: the pty is raw
    pty.write(payload)
    assert host.read(len(payload)) == payload
    host.write(payload[::-1])
    assert read_until(pty.read, len(payload)) == payload[::-1]
    assert pty.bytes_dropped == 0


def test_disconnect_fails_the_clients_reads_and_removes_the_path(pty, client):
    host = client(pty.path)
    pty.disconnect()
    assert not pty.connected and not pty.path.exists() and not pty.path.is_symlink()
    with pytest.raises(serial.SerialException):
        host.read(1)
    with pytest.raises(serial.SerialException):
        client(pty.path)
    assert pty.read() == b"" and pty.write(b"lost") is None  # a disconnected port reads and writes nothing
    pty.disconnect()  # twice is harmless


def test_connect_again_serves_a_new_client_at_the_same_path(pty, client):
    path = pty.path
    client(path)
    pty.disconnect()
    pty.connect()
    assert pty.connected and pty.path == path
    host = client(path)
    pty.write(b"\x00again\x00")
    assert host.read(7) == b"\x00again\x00"
    host.write(b"back")
    assert read_until(pty.read, 4) == b"back"


def test_writes_nobody_reads_never_block():
    port = PtyPort()  # a fresh temporary path
    try:
        chunk = bytes(range(1, 256)) * 4  # 1020 bytes
        started = time.perf_counter()
        for _ in range(1028):  # ~1 MB
            port.write(chunk)
        elapsed = time.perf_counter() - started
        assert 0 < port.bytes_dropped < 1028 * len(chunk)
        assert elapsed < 1.0  # measured: a few ms
    finally:
        port.close()
    assert not port.path.exists()


# --- UrlPort -------------------------------------------------------------------------------------------


def test_a_url_port_on_loop_round_trips_bytes():
    port = UrlPort("loop://")
    try:
        assert port.connected and port.read() == b""
        port.write(b"\x01\x02\x00frame\x00")
        assert port.bytes_dropped == 0 and port.read() == b"\x01\x02\x00frame\x00"
    finally:
        port.close()


def test_a_url_port_disconnects_and_connects_again():
    port = UrlPort("loop://")
    try:
        assert port.connected
        port.disconnect()
        assert not port.connected and port.read() == b"" and port.write(b"x") is None
        port.disconnect()  # twice is harmless
        port.connect()
        assert port.connected and port.read() == b""
    finally:
        port.close()
    assert not port.connected


def test_a_url_port_on_a_socket_reads_what_has_arrived_in_one_call():
    """pyserial's socket:// says in_waiting = 1 whenever readable: the port reads a chunk with timeout 0 instead."""
    import socket

    with socket.create_server(("127.0.0.1", 0)) as server:
        port = UrlPort(f"socket://127.0.0.1:{server.getsockname()[1]}")
        peer, _ = server.accept()
        try:
            peer.settimeout(1.0)
            port.write(b"drive\x00")
            assert port.bytes_dropped == 0 and peer.recv(64) == b"drive\x00"
            peer.sendall(bytes(range(1, 38)))  # one MEASUREMENT's worth: one segment on loopback
            time.sleep(0.01)
            assert port.read() == bytes(range(1, 38))
        finally:
            peer.close()
            port.close()


def test_a_url_port_whose_peer_goes_away_is_down_not_broken():
    """A socket closed by the far end (a serial server gone, a device unplugged) is a failure the port counts and
    reports; it does not raise into the rig's tick."""
    import socket

    with socket.create_server(("127.0.0.1", 0)) as server:
        port = UrlPort(f"socket://127.0.0.1:{server.getsockname()[1]}")
        peer, _ = server.accept()
        peer.close()
        try:
            assert read_until(port.read, 1, timeout_s=0.3) == b""
            assert (port.failures, port.connected) == (1, False) and "disconnected" in port.last_error
            port.write(b"frame\x00")  # down: nothing is written, nothing raised
            port.connect()  # the server is still there: a new connection
            assert port.connected
        finally:
            port.close()


# --- the emulator on a port that fails -----------------------------------------------------------------


def test_the_emulator_reports_a_failed_port_and_reopens_it_every_interval():
    """The first attempt comes at once, the next REOPEN_INTERVAL_S of rig time later."""
    import socket

    from nfal.apps.rig_emulator import REOPEN_INTERVAL_S, Emulator

    events: list[str] = []
    with socket.create_server(("127.0.0.1", 0)) as server:
        emulator = Emulator(UrlPort(f"socket://127.0.0.1:{server.getsockname()[1]}"), StillRig(),
                            on_event=events.append)
        port, attempts = emulator.port, []
        connect = port.connect

        def counted_connect() -> None:
            attempts.append(len(attempts))
            if len(attempts) == 1:
                raise LinkError("cannot open: refused (a test)")
            connect()

        port.connect = counted_connect
        server.accept()[0].close()
        k = 0
        while emulator.report.disconnects == 0 and k < 200:
            emulator.tick(k)
            k += 1
            time.sleep(0.001)
        assert emulator.report.disconnects == 1 and any("port failed" in event for event in events)
        assert len(attempts) == 1 and not port.connected  # at once, refused
        ticks_per_reopen = round(REOPEN_INTERVAL_S / emulator.timing.sample_period_s)
        for k in range(k, k + ticks_per_reopen - 2):
            emulator.tick(k)
        assert len(attempts) == 1  # not before the interval
        for k in range(k + 1, k + 4):
            emulator.tick(k)
        assert len(attempts) == 2 and port.connected and any("port reopened" in event for event in events)
        server.accept()[0].close()
        port.close()
