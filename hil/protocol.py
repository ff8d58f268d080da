"""The nfal rig protocol, version 1: framing, messages and a decoder that never trusts a byte.

docs/protocol.md is the specification (a firmware author implements it from that alone); this module
is the reference implementation. In short:

* A **frame** on the wire is ``COBS(type u8 | seq u32 | body | crc u32) 0x00``. COBS (Consistent
  Overhead Byte Stuffing, the ``cobs`` package) removes every zero byte, so ``0x00`` only ever ends a
  frame and a receiver resynchronises at the next one after any damage.
* **Byte order** little-endian; reals are IEEE-754 binary32 in SI units.
* **CRC** CRC-32/ISO-HDLC (zlib's ``crc32``: poly 0x04C11DB7 reflected, init and xorout 0xFFFFFFFF)
  over type, seq and body.
* **seq**: each sender counts its frames from 0 (mod 2^32, RFC 1982 serial arithmetic); a receiver
  uses only frames newer than the last it accepted. HELLO (host) and HELLO_ACK (rig) start a session
  and are accepted whatever their seq; they reset the receiver's sequence.

:class:`FrameDecoder` turns bytes into messages and counts every frame it drops (:class:`DecoderCounters`).
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import math
import struct
import zlib
from typing import ClassVar

from cobs import cobs

#: The protocol version this module speaks (HELLO / HELLO_ACK carry it; both sides must agree).
PROTOCOL_VERSION = 1
#: Longest frame before stuffing (type + seq + body + crc) [bytes]; anything longer is dropped.
MAX_FRAME_BYTES = 64
#: Longest stuffed frame, without its delimiter: COBS adds one byte per 254 and one in front.
MAX_ENCODED_BYTES = MAX_FRAME_BYTES + MAX_FRAME_BYTES // 254 + 1
DELIMITER = b"\x00"
_HEADER = struct.Struct("<BI")
_CRC = struct.Struct("<I")
_SEQ_MODULUS = 1 << 32


class MessageType(enum.IntEnum):
    """The type byte. 0x0_: host to rig; 0x8_: rig to host."""

    HELLO = 0x01
    DRIVE = 0x02
    STOP = 0x03
    HOST_HEARTBEAT = 0x04
    HELLO_ACK = 0x81
    MEASUREMENT = 0x82
    RIG_HEARTBEAT = 0x83
    FAULT = 0x84


class StatusFlags(enum.IntFlag):
    """The rig's status word (MEASUREMENT, RIG_HEARTBEAT)."""

    PLL_LOCKED = 0x0001          #: the resonance tracker is locked
    SESSION_ACTIVE = 0x0002      #: a host has said HELLO and not STOP
    WATCHDOG_TRIPPED = 0x0004    #: no DRIVE for the watchdog time: the drive is ramping down / down
    DRIVE_LIMITED = 0x0008       #: the commanded voltage was above the rig's limit and was clamped
    RESTING = 0x0010             #: the object rests on the driving surface
    SENSOR_OUT_OF_RANGE = 0x0020  #: the height sensor is saturated; the height is its range limit


class FaultCode(enum.IntEnum):
    """FAULT codes: what went wrong on the rig (``detail`` is a number that qualifies it)."""

    WATCHDOG = 1          #: detail: seconds since the last DRIVE
    BAD_FRAME = 2         #: detail: frames the rig has dropped so far
    VERSION_MISMATCH = 3  #: detail: the version the host asked for
    DRIVE_LIMITED = 4     #: detail: the commanded voltage [V]
    SENSOR_RANGE = 5      #: detail: the raw height [m]


@dataclasses.dataclass(frozen=True)
class Message:
    """Base of the messages; ``TYPE`` and ``LAYOUT`` (struct format of the body) per subclass."""

    TYPE: ClassVar[MessageType]
    LAYOUT: ClassVar[struct.Struct] = struct.Struct("<")

    @classmethod
    @functools.cache
    def field_names(cls) -> tuple[str, ...]:
        return tuple(field.name for field in dataclasses.fields(cls))

    def values(self) -> tuple:
        """The fields in body order."""
        return tuple(getattr(self, name) for name in self.field_names())

    def pack_body(self) -> bytes:
        return self.LAYOUT.pack(*self.values())

    def is_valid(self) -> bool:
        """Whether the values make sense: every real finite (and more, per type)."""
        return all(math.isfinite(v) for v in self.values() if isinstance(v, float))

    @classmethod
    def unpack_body(cls, body: bytes) -> "Message":
        return cls(*cls.LAYOUT.unpack(body))


@dataclasses.dataclass(frozen=True)
class Hello(Message):
    """Host -> rig: open a session with ``protocol_version``."""

    TYPE = MessageType.HELLO
    LAYOUT = struct.Struct("<H")
    protocol_version: int = PROTOCOL_VERSION


@dataclasses.dataclass(frozen=True)
class Drive(Message):
    """Host -> rig: drive voltage amplitude [V] from now on (feeds the watchdog)."""

    TYPE = MessageType.DRIVE
    LAYOUT = struct.Struct("<f")
    voltage: float

    def is_valid(self) -> bool:
        return math.isfinite(self.voltage) and self.voltage >= 0.0


@dataclasses.dataclass(frozen=True)
class Stop(Message):
    """Host -> rig: end the session; the rig ramps the drive down."""

    TYPE = MessageType.STOP


@dataclasses.dataclass(frozen=True)
class HostHeartbeat(Message):
    """Host -> rig: the host is alive (does NOT feed the watchdog: only DRIVE does)."""

    TYPE = MessageType.HOST_HEARTBEAT


@dataclasses.dataclass(frozen=True)
class HelloAck(Message):
    """Rig -> host: the answer to HELLO, with the rig's timing and limits."""

    TYPE = MessageType.HELLO_ACK
    LAYOUT = struct.Struct("<HIIIf")
    protocol_version: int
    sample_period_us: int       #: measurement period [µs]
    watchdog_timeout_us: int    #: no DRIVE for this long trips the watchdog [µs]
    ramp_down_us: int           #: the watchdog's ramp from the last voltage to 0 V [µs]
    max_drive_voltage: float    #: commands above this are clamped [V]


@dataclasses.dataclass(frozen=True)
class Measurement(Message):
    """Rig -> host, once per sample period while a session is active."""

    TYPE = MessageType.MEASUREMENT
    LAYOUT = struct.Struct("<QfffHI")
    timestamp_us: int      #: the rig's clock at the sample [µs]
    height: float          #: measured clearance [m]
    drive_frequency: float  #: drive frequency set by the rig's PLL [Hz]
    drive_voltage: float   #: voltage applied from this sample on (the period it starts), after clamp and watchdog [V]
    status: int            #: :class:`StatusFlags`
    command_seq: int       #: seq of the last DRIVE applied (0 before any)


@dataclasses.dataclass(frozen=True)
class RigHeartbeat(Message):
    """Rig -> host, 10 times a second always: alive, status and what the rig has dropped."""

    TYPE = MessageType.RIG_HEARTBEAT
    LAYOUT = struct.Struct("<QHII")
    timestamp_us: int
    status: int
    frames_received: int
    frames_dropped: int


@dataclasses.dataclass(frozen=True)
class Fault(Message):
    """Rig -> host: a fault (:class:`FaultCode`), sent when it happens."""

    TYPE = MessageType.FAULT
    LAYOUT = struct.Struct("<QHf")
    timestamp_us: int
    code: int
    detail: float


MESSAGES: dict[int, type[Message]] = {cls.TYPE: cls for cls in
                                      (Hello, Drive, Stop, HostHeartbeat, HelloAck, Measurement, RigHeartbeat, Fault)}
HOST_TO_RIG = frozenset(t for t in MessageType if t < 0x80)
RIG_TO_HOST = frozenset(t for t in MessageType if t >= 0x80)
#: Frames that open a session: accepted whatever their seq, and they restart the sequence.
SESSION_OPENERS = frozenset({MessageType.HELLO, MessageType.HELLO_ACK})


def encode(message: Message, seq: int) -> bytes:
    """One frame on the wire: COBS-stuffed type, seq, body and CRC-32, then the 0x00 delimiter."""
    frame = _HEADER.pack(message.TYPE, seq % _SEQ_MODULUS) + message.pack_body()
    frame += _CRC.pack(zlib.crc32(frame))
    return cobs.encode(frame) + DELIMITER


def is_newer(seq: int, last: int) -> bool:
    """RFC 1982 serial-number order on 32 bits: ``seq`` comes after ``last``."""
    return 0 < (seq - last) % _SEQ_MODULUS < _SEQ_MODULUS // 2


@dataclasses.dataclass
class DecoderCounters:
    """What a :class:`FrameDecoder` has seen. Every dropped frame is counted in exactly one field."""

    frames_ok: int = 0       #: frames decoded and handed on
    cobs_errors: int = 0     #: stuffing that does not decode (damaged bytes)
    crc_errors: int = 0      #: CRC mismatch (damaged bytes)
    truncated: int = 0       #: shorter than type + seq + crc, or a body shorter than its type's
    oversized: int = 0       #: longer than MAX_FRAME_BYTES (or a body longer than its type's)
    unknown_type: int = 0    #: a type this receiver does not take
    invalid_value: int = 0   #: an intact frame with a value out of range (a real not finite, a negative voltage)
    out_of_order: int = 0    #: seq not newer than the last accepted (duplicates included)
    lost: int = 0            #: frames missing from the sequence (gaps between accepted seqs)

    @property
    def dropped(self) -> int:
        """Frames received but not used."""
        return (self.cobs_errors + self.crc_errors + self.truncated + self.oversized + self.unknown_type
                + self.invalid_value + self.out_of_order)

    def as_dict(self) -> dict[str, int]:
        return {**dataclasses.asdict(self), "dropped": self.dropped}


@dataclasses.dataclass(frozen=True)
class Received:
    """A decoded frame: its seq and message."""

    seq: int
    message: Message


class FrameDecoder:
    """Bytes in, messages out: split at 0x00, unstuff, check length, CRC, type and order; count drops.

    Parameters
    ----------
    accepts : set of MessageType
        The types this side takes (:data:`RIG_TO_HOST` on the host, :data:`HOST_TO_RIG` on the rig).
    """

    def __init__(self, accepts: frozenset[int]) -> None:
        self.accepts = frozenset(accepts)
        self.counters = DecoderCounters()
        self.last_seq: int | None = None
        self._pending = bytearray()
        self._overflowing = False

    @property
    def mid_frame(self) -> bool:
        """Bytes of a frame are waiting for the rest of it (a reader that takes over the stream skips to the next
        delimiter)."""
        return bool(self._pending) or self._overflowing

    def reset_sequence(self) -> None:
        """Forget the last seq (a new session: the peer restarts its count)."""
        self.last_seq = None

    def feed(self, data: bytes) -> list[Received]:
        """Decode every complete frame in ``data`` (with what was left from earlier calls)."""
        out: list[Received] = []
        *frames, rest = bytes(data).split(DELIMITER)
        for chunk in frames:
            if self._overflowing:  # the tail of an oversized frame (already counted)
                self._overflowing = False
                self._pending.clear()
                continue
            self._pending += chunk
            encoded = bytes(self._pending)
            self._pending.clear()
            if encoded:  # back-to-back delimiters are idle fill, not frames
                received = self._decode(encoded)
                if received is not None:
                    out.append(received)
        if not self._overflowing:
            self._pending += rest
            if len(self._pending) > MAX_ENCODED_BYTES:
                self.counters.oversized += 1
                self._overflowing = True
                self._pending.clear()
        return out

    def _decode(self, encoded: bytes) -> Received | None:
        counters = self.counters
        if len(encoded) > MAX_ENCODED_BYTES:
            counters.oversized += 1
            return None
        try:
            frame = cobs.decode(encoded)
        except cobs.DecodeError:
            counters.cobs_errors += 1
            return None
        if len(frame) < _HEADER.size + _CRC.size:
            counters.truncated += 1
            return None
        if len(frame) > MAX_FRAME_BYTES:
            counters.oversized += 1
            return None
        payload, (crc,) = frame[:-_CRC.size], _CRC.unpack(frame[-_CRC.size:])
        if zlib.crc32(payload) != crc:
            counters.crc_errors += 1
            return None
        kind, seq = _HEADER.unpack_from(payload)
        cls = MESSAGES.get(kind)
        if cls is None or kind not in self.accepts:
            counters.unknown_type += 1
            return None
        body = payload[_HEADER.size:]
        if len(body) != cls.LAYOUT.size:
            if len(body) < cls.LAYOUT.size:
                counters.truncated += 1
            else:
                counters.oversized += 1
            return None
        message = cls.unpack_body(body)
        if not message.is_valid():
            counters.invalid_value += 1
            return None
        if kind in SESSION_OPENERS:
            self.last_seq = None
        elif self.last_seq is not None and not is_newer(seq, self.last_seq):
            counters.out_of_order += 1
            return None
        if self.last_seq is not None:
            counters.lost += (seq - self.last_seq) % _SEQ_MODULUS - 1
        self.last_seq = seq
        counters.frames_ok += 1
        return Received(seq, message)


class FrameEncoder:
    """Numbers one sender's frames: ``encoder(message) -> bytes`` with seq 0, 1, 2, ... (mod 2^32)."""

    def __init__(self) -> None:
        self.next_seq = 0

    def __call__(self, message: Message) -> bytes:
        seq, self.next_seq = self.next_seq, (self.next_seq + 1) % _SEQ_MODULUS
        return encode(message, seq)

    @property
    def last_seq(self) -> int:
        """The seq of the last frame numbered."""
        return (self.next_seq - 1) % _SEQ_MODULUS

    def restart(self) -> None:
        """Count from 0 again (a new session)."""
        self.next_seq = 0
