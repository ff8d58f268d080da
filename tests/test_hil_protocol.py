"""The rig protocol (nfal.hil.protocol): framing, CRC, sequence numbers and the decoder's drops.

The example frames are those of docs/protocol.md, so the specification and the code cannot drift.
"""

from __future__ import annotations

import math
import struct
import zlib
from pathlib import Path

import pytest
from cobs import cobs
from helpers.properties import examples
from hypothesis import given
from hypothesis import strategies as st

from nfal.hil.protocol import (
    HOST_TO_RIG, MAX_ENCODED_BYTES, MAX_FRAME_BYTES, MESSAGES, PROTOCOL_VERSION, RIG_TO_HOST, SESSION_OPENERS,
    Drive, Fault, FaultCode, FrameDecoder, FrameEncoder, Hello, HelloAck, HostHeartbeat, Measurement, MessageType,
    Received, RigHeartbeat, StatusFlags, Stop, encode, is_newer,
)

DOC = Path(__file__).resolve().parents[1] / "docs" / "protocol.md"
EXAMPLES = examples(250)

u16, u32, u64 = (st.integers(0, 2**bits - 1) for bits in (16, 32, 64))
real = st.floats(width=32, allow_nan=False, allow_infinity=False)
voltage = st.floats(min_value=0.0, width=32, allow_nan=False, allow_infinity=False)
STRATEGIES = {
    Hello: st.builds(Hello, u16),
    Drive: st.builds(Drive, voltage),
    Stop: st.just(Stop()),
    HostHeartbeat: st.just(HostHeartbeat()),
    HelloAck: st.builds(HelloAck, u16, u32, u32, u32, real),
    Measurement: st.builds(Measurement, u64, real, real, real, u16, u32),
    RigHeartbeat: st.builds(RigHeartbeat, u64, u16, u32, u32),
    Fault: st.builds(Fault, u64, u16, real),
}
any_message = st.one_of(*STRATEGIES.values())
host_messages = st.one_of(*(s for cls, s in STRATEGIES.items() if cls.TYPE in HOST_TO_RIG))
rig_messages = st.one_of(*(s for cls, s in STRATEGIES.items() if cls.TYPE in RIG_TO_HOST))
#: Rig messages that do not open a session (so one encoder's seqs are the whole story).
rig_stream_messages = st.one_of(STRATEGIES[Measurement], STRATEGIES[RigHeartbeat], STRATEGIES[Fault])
DIRECTIONS = pytest.mark.parametrize("accepts, messages", [(RIG_TO_HOST, rig_messages), (HOST_TO_RIG, host_messages)],
                                     ids=["host decodes rig", "rig decodes host"])


def raw_frame(kind: int, seq: int, body: bytes) -> bytes:
    """A frame built by hand from the specification (struct, zlib, cobs), not by ``encode``."""
    frame = struct.pack("<BI", kind, seq) + body
    return cobs.encode(frame + struct.pack("<I", zlib.crc32(frame))) + b"\x00"


def crc32_bitwise(data: bytes) -> int:
    """docs/protocol.md's C snippet, in Python."""
    crc = 0xFFFFFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ (0xEDB88320 & -(crc & 1))
    return crc ^ 0xFFFFFFFF


def feed_in_chunks(decoder: FrameDecoder, stream: bytes, cuts: list[int]) -> list[Received]:
    """Feed ``stream`` cut at ``cuts`` (any positions, any order)."""
    bounds = [0, *sorted(min(cut, len(stream)) for cut in cuts), len(stream)]
    return [received for start, stop in zip(bounds, bounds[1:]) for received in decoder.feed(stream[start:stop])]


def frame_spans(frames: list[bytes]) -> list[tuple[int, int]]:
    """(first byte, delimiter) positions of each frame in their concatenation."""
    ends = [sum(map(len, frames[:k + 1])) - 1 for k in range(len(frames))]
    return [(end - len(frame) + 1, end) for frame, end in zip(frames, ends)]


def hex_of(data: bytes) -> str:
    return " ".join(f"{byte:02x}" for byte in data)


cuts = st.lists(st.integers(0, 2000), max_size=12)


# --- Round trip and framing -------------------------------------------------------------------------

@DIRECTIONS
@EXAMPLES
@given(data=st.data())
def test_any_messages_in_any_chunking_come_back_equal_in_order(accepts, messages, data):
    sent = data.draw(st.lists(messages, max_size=20))
    encoder, decoder = FrameEncoder(), FrameDecoder(accepts)
    stream = b"".join(encoder(message) for message in sent)
    received = feed_in_chunks(decoder, stream, data.draw(cuts))
    assert received == [Received(seq, message) for seq, message in enumerate(sent)]
    assert decoder.counters.as_dict() == {**dict.fromkeys(decoder.counters.as_dict(), 0), "frames_ok": len(sent)}


@EXAMPLES
@given(message=any_message, seq=st.integers(0, 2**33))
def test_a_frame_has_no_zero_but_its_delimiter_and_fits(message, seq):
    frame = encode(message, seq)
    assert frame[-1] == 0 and 0 not in frame[:-1]
    assert len(frame) == 1 + 5 + message.LAYOUT.size + 4 + 1 <= MAX_ENCODED_BYTES + 1
    assert frame == raw_frame(message.TYPE, seq % 2**32, message.LAYOUT.pack(*message.values()))


@pytest.mark.parametrize("cls, body_bytes, wire_bytes", [
    (Hello, 2, 13), (Drive, 4, 15), (Stop, 0, 11), (HostHeartbeat, 0, 11),
    (HelloAck, 18, 29), (Measurement, 26, 37), (RigHeartbeat, 18, 29), (Fault, 14, 25),
])
def test_message_sizes_are_the_documented_ones(cls, body_bytes, wire_bytes):
    message = cls(*(0,) * len(cls.field_names()))
    assert cls.LAYOUT.size == body_bytes and len(encode(message, 0)) == wire_bytes
    assert 5 + body_bytes + 4 <= MAX_FRAME_BYTES


def test_type_bytes_flags_and_codes_are_the_documented_ones():
    assert {t.name: t.value for t in MessageType} == {
        "HELLO": 0x01, "DRIVE": 0x02, "STOP": 0x03, "HOST_HEARTBEAT": 0x04,
        "HELLO_ACK": 0x81, "MEASUREMENT": 0x82, "RIG_HEARTBEAT": 0x83, "FAULT": 0x84}
    assert HOST_TO_RIG == {1, 2, 3, 4} and RIG_TO_HOST == {0x81, 0x82, 0x83, 0x84}
    assert SESSION_OPENERS == {MessageType.HELLO, MessageType.HELLO_ACK} and set(MESSAGES) == set(MessageType)
    assert {f.name: f.value for f in StatusFlags} == {
        "PLL_LOCKED": 1, "SESSION_ACTIVE": 2, "WATCHDOG_TRIPPED": 4, "DRIVE_LIMITED": 8, "RESTING": 16,
        "SENSOR_OUT_OF_RANGE": 32}
    assert {c.name: c.value for c in FaultCode} == {
        "WATCHDOG": 1, "BAD_FRAME": 2, "VERSION_MISMATCH": 3, "DRIVE_LIMITED": 4, "SENSOR_RANGE": 5}
    assert PROTOCOL_VERSION == 1 and (MAX_FRAME_BYTES, MAX_ENCODED_BYTES) == (64, 65)


# --- CRC and the documented vectors -----------------------------------------------------------------

def test_crc_is_crc32_iso_hdlc():
    """The check value of CRC-32/ISO-HDLC, by zlib and by the documented bitwise algorithm."""
    assert zlib.crc32(b"123456789") == crc32_bitwise(b"123456789") == 0xCBF43926


@EXAMPLES
@given(data=st.binary(max_size=64))
def test_the_documented_bitwise_crc_is_zlibs(data):
    assert crc32_bitwise(data) == zlib.crc32(data)


@pytest.mark.parametrize("message, seq, unstuffed, wire", [
    (Drive(voltage=100.0), 7,
     "02 07 00 00 00 00 00 c8 42 cb 48 cb 59",
     "03 02 07 01 01 01 01 07 c8 42 cb 48 cb 59 00"),
    (Measurement(1_500_000, 1e-4, 28500.0, 100.0, StatusFlags.PLL_LOCKED | StatusFlags.SESSION_ACTIVE, 2999), 3000,
     "82 b8 0b 00 00 60 e3 16 00 00 00 00 00 17 b7 d1 38 00 a8 de 46 00 00 c8 42 03 00 b7 0b 00 00 97 74 29 09",
     "04 82 b8 0b 01 04 60 e3 16 01 01 01 01 05 17 b7 d1 38 04 a8 de 46 01 04 c8 42 03 03 b7 0b 01 05 97 74 29 09 00"),
], ids=["DRIVE", "MEASUREMENT"])
def test_documented_frames(message, seq, unstuffed, wire):
    frame = encode(message, seq)
    assert hex_of(frame) == wire and hex_of(cobs.decode(frame[:-1])) == unstuffed
    assert crc32_bitwise(bytes.fromhex(unstuffed)[:-4]) == int.from_bytes(bytes.fromhex(unstuffed)[-4:], "little")
    text = DOC.read_text(encoding="utf-8")
    assert unstuffed in text and wire in text


# --- Garbage and damage -----------------------------------------------------------------------------

@DIRECTIONS
@EXAMPLES
@given(data=st.data())
def test_any_bytes_in_any_chunking_never_raise_and_yield_only_sound_frames(accepts, messages, data):
    """Garbage mixed with frames of any seq: what comes out was sent whole, and chunking changes nothing."""
    pieces = data.draw(st.lists(st.one_of(st.binary(max_size=90), st.builds(encode, any_message, u32)), max_size=12))
    stream = b"".join(pieces)
    whole, chunked = FrameDecoder(accepts), FrameDecoder(accepts)
    received = whole.feed(stream)
    assert feed_in_chunks(chunked, stream, data.draw(cuts)) == received
    assert chunked.counters == whole.counters and whole.counters.frames_ok == len(received)
    chunks = set(stream.split(b"\x00"))
    for item in received:
        message = item.message
        assert message.TYPE in accepts
        assert all(math.isfinite(v) for v in message.values() if isinstance(v, float))
        assert encode(message, item.seq)[:-1] in chunks
        assert FrameDecoder(accepts).feed(encode(message, item.seq)) == [item]


@st.composite
def damaged_stream(draw):
    """(messages, frames, damaged stream, positions altered or deleted, positions inserted before)."""
    messages = draw(st.lists(rig_stream_messages, min_size=1, max_size=12))
    encoder = FrameEncoder()
    frames = [encoder(message) for message in messages]
    stream = bytearray(b"".join(frames))
    operations = draw(st.lists(
        st.tuples(st.integers(0, len(stream) - 1), st.sampled_from(["alter", "insert", "delete"]),
                  st.binary(min_size=1, max_size=4)),
        max_size=8, unique_by=lambda operation: operation[0]))
    for position, kind, value in sorted(operations, reverse=True):
        if kind == "alter":
            stream[position] = value[0] if value[0] != stream[position] else value[0] ^ 0x80
        elif kind == "insert":
            stream[position:position] = value
        else:
            del stream[position]
    changed = {position for position, kind, _ in operations if kind != "insert"}
    inserted = {position for position, kind, _ in operations if kind == "insert"}
    return messages, frames, bytes(stream), changed, inserted


@EXAMPLES
@given(damaged=damaged_stream(), chunking=cuts)
def test_damage_never_yields_anything_but_intact_originals(damaged, chunking):
    """Bytes altered, inserted, deleted anywhere (delimiters too): only frames received whole come out,
    with their seq, in order; every frame whose bytes and both delimiters are untouched comes out."""
    messages, frames, stream, changed, inserted = damaged
    decoder = FrameDecoder(RIG_TO_HOST)
    received = feed_in_chunks(decoder, stream, chunking)
    seqs = [item.seq for item in received]
    assert all(0 <= seq < len(messages) and item == Received(seq, messages[seq]) for seq, item in zip(seqs, received))
    assert seqs == sorted(set(seqs))
    chunks = set(stream.split(b"\x00"))
    assert all(frames[seq][:-1] in chunks for seq in seqs)
    intact = [seq for seq, (first, delimiter) in enumerate(frame_spans(frames))
              if not changed & set(range(first - 1, delimiter + 1)) and not inserted & set(range(first, delimiter + 1))]
    assert set(intact) <= set(seqs)
    counters = decoder.counters
    assert counters.frames_ok == len(received) and counters.out_of_order == 0
    if seqs:
        assert counters.frames_ok + counters.lost == seqs[-1] - seqs[0] + 1


@EXAMPLES
@given(data=st.data())
def test_bytes_altered_inside_frames_drop_exactly_those_frames(data):
    """Non-zero bytes changed to other non-zero bytes keep every delimiter: each frame is either
    yielded (untouched) or counted once as a COBS or CRC error, and the gaps between yields are lost."""
    messages = data.draw(st.lists(rig_stream_messages, min_size=1, max_size=12))
    encoder = FrameEncoder()
    frames = [encoder(message) for message in messages]
    stream = bytearray(b"".join(frames))
    inside = [position for position, byte in enumerate(stream) if byte]
    alterations = data.draw(st.lists(st.tuples(st.sampled_from(inside), st.integers(1, 254)), max_size=8,
                                     unique_by=lambda alteration: alteration[0]))
    for position, shift in alterations:
        stream[position] = (stream[position] - 1 + shift) % 255 + 1
    decoder = FrameDecoder(RIG_TO_HOST)
    received = feed_in_chunks(decoder, bytes(stream), data.draw(cuts))
    altered = {position for position, _ in alterations}
    untouched = [seq for seq, (first, delimiter) in enumerate(frame_spans(frames))
                 if not altered & set(range(first, delimiter))]
    assert received == [Received(seq, messages[seq]) for seq in untouched]
    counters = decoder.counters
    assert counters.frames_ok + counters.dropped == len(messages)
    assert counters.cobs_errors + counters.crc_errors == counters.dropped
    if untouched:
        assert counters.lost == untouched[-1] - untouched[0] + 1 - len(untouched)


NEXT = RigHeartbeat(123, 3, 10, 0)
MEASUREMENT_FRAME = encode(Measurement(1_500_000, 1e-4, 28500.0, 100.0, 3, 2999), 3000)


@pytest.mark.parametrize("kept", range(1, len(MEASUREMENT_FRAME) - 1))
def test_a_frame_cut_short_is_dropped_and_the_next_decodes(kept):
    decoder = FrameDecoder(RIG_TO_HOST)
    assert decoder.feed(MEASUREMENT_FRAME[:kept] + b"\x00" + encode(NEXT, 3001)) == [Received(3001, NEXT)]
    counters = decoder.counters
    assert counters.truncated + counters.cobs_errors + counters.crc_errors == counters.dropped == 1


def test_idle_fill_is_not_a_frame():
    decoder = FrameDecoder(RIG_TO_HOST)
    assert decoder.feed(b"\x00\x00" + encode(NEXT, 1) + b"\x00" * 5) == [Received(1, NEXT)]
    assert decoder.counters.dropped == 0


@pytest.mark.parametrize("bytewise", [False, True], ids=["whole", "byte by byte"])
@pytest.mark.parametrize("run, counter", [
    (MAX_ENCODED_BYTES, "crc_errors"), (MAX_ENCODED_BYTES + 1, "oversized"), (200, "oversized"), (5000, "oversized"),
])
def test_a_long_run_is_one_oversized_frame_and_the_next_decodes(run, counter, bytewise):
    """0x01 * n unstuffs to n - 1 zeros: at 65 bytes a (bad) frame of 64, beyond it oversized."""
    stream = b"\x01" * run + b"\x00" + encode(NEXT, 9)
    decoder = FrameDecoder(RIG_TO_HOST)
    received = feed_in_chunks(decoder, stream, list(range(len(stream))) if bytewise else [])
    assert received == [Received(9, NEXT)]
    assert getattr(decoder.counters, counter) == decoder.counters.dropped == 1


# --- Checks after the CRC ---------------------------------------------------------------------------

@pytest.mark.parametrize("accepts", [RIG_TO_HOST, HOST_TO_RIG], ids=["host", "rig"])
@pytest.mark.parametrize("kind", [*MessageType, 0x00, 0x05, 0x7F, 0x80, 0x85, 0xFF], ids=hex)
def test_a_type_of_the_other_direction_or_of_no_one_is_unknown(accepts, kind):
    cls = MESSAGES.get(kind)
    body = bytes(cls.LAYOUT.size) if cls else b""
    decoder = FrameDecoder(accepts)
    received = decoder.feed(raw_frame(kind, 0, body))
    taken = kind in accepts
    assert len(received) == taken and decoder.counters.unknown_type == (not taken)


@pytest.mark.parametrize("bits", [0x7FC00000, 0xFFC00000, 0x7F800001, 0x7F800000, 0xFF800000],
                         ids=["nan", "-nan", "snan", "inf", "-inf"])
@pytest.mark.parametrize("cls, offset, accepts", [
    (Drive, 0, HOST_TO_RIG), (HelloAck, 14, RIG_TO_HOST), (Measurement, 8, RIG_TO_HOST),
    (Measurement, 12, RIG_TO_HOST), (Measurement, 16, RIG_TO_HOST), (Fault, 10, RIG_TO_HOST),
], ids=["DRIVE.voltage", "HELLO_ACK.max_drive_voltage", "MEASUREMENT.height", "MEASUREMENT.drive_frequency",
        "MEASUREMENT.drive_voltage", "FAULT.detail"])
def test_a_non_finite_real_in_an_intact_frame_is_invalid(cls, offset, accepts, bits):
    body = bytearray(cls.LAYOUT.size)
    body[offset:offset + 4] = struct.pack("<I", bits)
    decoder = FrameDecoder(accepts)
    assert decoder.feed(raw_frame(cls.TYPE, 4, bytes(body))) == []
    assert decoder.counters.invalid_value == decoder.counters.dropped == 1


@pytest.mark.parametrize("voltage", [-1e-6, -5.0, -150.0])
def test_a_negative_drive_voltage_is_invalid(voltage):
    decoder = FrameDecoder(HOST_TO_RIG)
    assert decoder.feed(encode(Drive(voltage), 1)) == []
    assert decoder.counters.invalid_value == decoder.counters.dropped == 1 and decoder.counters.frames_ok == 0


@pytest.mark.parametrize("cls, size, counter", [
    (Drive, 3, "truncated"), (Drive, 5, "oversized"), (Stop, 1, "oversized"), (Hello, 0, "truncated"),
])
def test_a_body_of_the_wrong_length_is_dropped(cls, size, counter):
    decoder = FrameDecoder(HOST_TO_RIG)
    assert decoder.feed(raw_frame(cls.TYPE, 0, b"\x01" * size)) == []
    assert getattr(decoder.counters, counter) == decoder.counters.dropped == 1


@pytest.mark.parametrize("chunk", [b"\x01", b"\x09" + b"\x01" * 8, b"\x05\x01\x02\x03\x04"])
def test_a_frame_shorter_than_its_header_and_crc_is_truncated(chunk):
    decoder = FrameDecoder(RIG_TO_HOST)
    assert decoder.feed(chunk + b"\x00") == [] and decoder.counters.truncated == 1


# --- Sequence numbers -------------------------------------------------------------------------------

@pytest.mark.parametrize("seq, last, newer", [
    (1, 0, True), (0, 1, False), (7, 7, False), (0, 2**32 - 1, True), (2**32 - 1, 0, False),
    (2**31 - 1, 0, True), (2**31, 0, False), (0, 2**31, False), (5, 2**32 - 3, True),
])
def test_is_newer_is_rfc_1982(seq, last, newer):
    assert is_newer(seq, last) == newer


@EXAMPLES
@given(seq=u32, last=u32)
def test_of_two_seqs_one_is_newer_unless_equal_or_opposite(seq, last):
    if (seq - last) % 2**32 in (0, 2**31):
        assert not is_newer(seq, last) and not is_newer(last, seq)
    else:
        assert is_newer(seq, last) != is_newer(last, seq)


@pytest.mark.parametrize("sent, kept, out_of_order, lost", [
    ([5, 5, 4, 6], [5, 6], 2, 0),
    ([10, 9, 10, 11], [10, 11], 2, 0),
    ([0, 1, 3], [0, 1, 3], 0, 1),
    ([2**32 - 1, 0, 1], [2**32 - 1, 0, 1], 0, 0),
    ([2**32 - 2, 1], [2**32 - 2, 1], 0, 2),
    ([0, 2**31], [0], 1, 0),
    ([0, 2**31 - 1], [0, 2**31 - 1], 0, 2**31 - 2),
], ids=["duplicate and old", "old then duplicate", "gap", "wrap", "gap over wrap", "half way", "just under"])
def test_old_and_duplicate_frames_are_dropped_and_gaps_lost(sent, kept, out_of_order, lost):
    decoder = FrameDecoder(RIG_TO_HOST)
    received = decoder.feed(b"".join(encode(NEXT, seq) for seq in sent))
    assert [item.seq for item in received] == kept
    assert (decoder.counters.out_of_order, decoder.counters.lost) == (out_of_order, lost)


@pytest.mark.parametrize("accepts, frames, kept", [
    (RIG_TO_HOST, [(NEXT, 100), (NEXT, 101), (HelloAck(1, 500, 20000, 50000, 150.0), 0), (NEXT, 1)], [100, 101, 0, 1]),
    (RIG_TO_HOST, [(NEXT, 100), (NEXT, 1)], [100]),
    (RIG_TO_HOST, [(HelloAck(1, 500, 20000, 50000, 150.0), 0)] * 2, [0, 0]),
    (HOST_TO_RIG, [(Drive(5.0), 5), (Hello(), 0), (Drive(6.0), 1)], [5, 0, 1]),
    (HOST_TO_RIG, [(Drive(5.0), 5), (Hello(), 3), (Drive(6.0), 4)], [5, 3, 4]),
], ids=["HELLO_ACK restarts", "no restart without it", "repeated HELLO_ACK", "HELLO restarts", "HELLO at any seq"])
def test_a_session_opener_is_taken_whatever_its_seq_and_restarts_the_sequence(accepts, frames, kept):
    decoder = FrameDecoder(accepts)
    received = decoder.feed(b"".join(encode(message, seq) for message, seq in frames))
    assert [item.seq for item in received] == kept
    assert decoder.counters.lost == 0 and decoder.counters.out_of_order == len(frames) - len(kept)


def test_a_restarted_rig_is_heard_again_after_its_hello_ack():
    old_rig, new_rig, host = FrameEncoder(), FrameEncoder(), FrameDecoder(RIG_TO_HOST)
    before = host.feed(b"".join(old_rig(NEXT) for _ in range(50)))
    ack = HelloAck(PROTOCOL_VERSION, 500, 20000, 50000, 150.0)
    after = host.feed(new_rig(NEXT) + new_rig(ack) + new_rig(NEXT) + new_rig(NEXT))
    assert len(before) == 50 and [item.seq for item in after] == [1, 2, 3]
    assert host.counters.out_of_order == 1 and host.counters.lost == 0
    new_rig.restart()
    assert host.feed(new_rig(ack) + new_rig(NEXT)) == [Received(0, ack), Received(1, NEXT)]


def test_the_encoder_counts_mod_2_32():
    encoder = FrameEncoder()
    encoder.next_seq = 2**32 - 1
    decoder = FrameDecoder(RIG_TO_HOST)
    assert [item.seq for item in decoder.feed(encoder(NEXT) + encoder(NEXT))] == [2**32 - 1, 0]
    assert decoder.counters.lost == 0
