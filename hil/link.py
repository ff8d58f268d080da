"""The host's side of the rig protocol: :class:`RigLink`, a session over any pyserial URL.

``serial.serial_for_url`` opens the port, so a device path (``/dev/ttyACM0``), a pty (the emulator's
path), ``loop://`` and ``socket://host:port`` are one code path. :meth:`RigLink.poll` takes in what the
port holds without waiting: it decodes the frames (:class:`~nfal.hil.protocol.FrameDecoder`), keeps
the newest measurement, the rig's faults and heartbeat, and reconnects when the port fails. Either a
daemon reader thread polls (blocking up to READ_TIMEOUT_S for the first byte; the default), or the
owner polls when it wants the news (``reader_thread=False``: the HardwareProxy polls at each step,
which costs less CPU than a thread woken 2000 times a second, and no GIL hand-overs). DRIVE frames
are written without blocking (``write_timeout=0``: a frame the port cannot take is counted, never
waited for), so nothing the link does can stall a co-simulation step.

A non-blocking poll drains the port (up to DRAIN_LIMIT bytes), so after a stall of the host the newest
sample is the newest the rig sent, not one of a backlog.

Reconnection: when a read or write fails (the device is unplugged, the emulator drops the pty) the
reader closes the port and, if ``reconnect``, reopens the URL every ``reconnect_interval_s`` and says
HELLO again; measurements resume after the rig's HELLO_ACK. An owner that polls never waits for the
port to open (a ``socket://`` connect can take seconds): a daemon thread opens it, and a later poll
says HELLO. Whoever uses the link decides how long it may go without measurements (the HardwareProxy
FMU: ``max_missed_samples``).
"""

from __future__ import annotations

import collections
import concurrent.futures
import dataclasses
import errno
import logging
import select
import threading
import time
from collections.abc import Callable

import serial

from nfal.errors import LinkError, require_duration, require_positive
from nfal.realtime import GapStats

from .protocol import (DELIMITER, PROTOCOL_VERSION, RIG_TO_HOST, Drive, Fault, FaultCode, FrameDecoder, FrameEncoder,
                       Hello, HelloAck, Measurement, RigHeartbeat, Stop)

logger = logging.getLogger(__name__)

#: Longest wait of one read [s]: how quickly the reader notices close().
READ_TIMEOUT_S = 0.01
#: Faults kept for :attr:`RigLink.faults`.
FAULT_HISTORY = 100
#: Most bytes one non-blocking read takes (about 100 measurement frames).
READ_CHUNK = 4096
#: Most bytes one non-blocking poll takes in (about 1700 measurement frames, 0.9 s of the stream at 2 kHz).
DRAIN_LIMIT = 16 * READ_CHUNK
#: A read this large (about 14 ms of the stream) means a backlog: the poll reads on until the port runs dry.
BACKLOG_BYTES = 1024
#: A HELLO without an answer this long is said again (spec 6: a frame lost on the wire) [s].
HELLO_REPEAT_S = 0.5
#: Only out-of-order frames for this long (three RIG_HEARTBEAT periods) means the rig restarted: HELLO again [s].
RESTART_SILENCE_S = 0.3
#: What a failed read raises (pyserial raises TypeError/AttributeError when the port is closed under a read).
READ_ERRORS = (serial.SerialException, OSError, TypeError, AttributeError)
#: Pause between two polls while an owner that polls waits for the rig [s] (not a busy spin).
WAIT_PAUSE_S = 2e-4
#: The longest gap between DRIVE commands that costs the object nothing worth a mention [s]: a drive held 5 ms at the
#: worst moment of a step adds at most 2.6 points of overshoot, 10 ms up to 133 (bench/watchdog_hold.py, docs/hil.md).
DRIVE_GAP_BUDGET_S = 5e-3
#: The longest the link waits for anything: a connection, a HELLO_ACK, a reconnection attempt [s].
LONGEST_WAIT_S = 60.0


def write_timeout(url: str) -> float | None:
    """The pyserial write timeout that never waits: 0, except for ``loop://``, which raises on any write
    longer than its timeout at the baud rate (it never blocks anyway: None)."""
    return None if url.startswith("loop://") else 0


def open_port(url: str, baudrate: int, read_timeout_s: float) -> serial.SerialBase:
    """``serial.serial_for_url`` with writes that never wait, and a device (or pty) locked for this process alone
    (pyserial's ``exclusive``: an flock, as serial terminals take it), so that a second host cannot take over a rig in
    use; raises LinkError naming the URL."""
    try:
        return serial.serial_for_url(url, baudrate=baudrate, timeout=read_timeout_s, write_timeout=write_timeout(url),
                                     exclusive=True)
    except serial.SerialException as exc:
        if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
            raise LinkError(f"{url} is in use by another program (another nfal identify or nfal run, or a serial "
                            "terminal): one host per rig; stop the other one first") from None
        raise LinkError(f"cannot open {url}: {exc}") from None
    except (OSError, ValueError) as exc:
        raise LinkError(f"cannot open {url}: {exc}") from None


@dataclasses.dataclass
class LinkCounters:
    """What happened on the link (the decoder's drops are in :attr:`RigLink.decoder`)."""

    measurements: int = 0       #: MEASUREMENT frames accepted
    measurements_before_session: int = 0  #: MEASUREMENT frames ignored because they came before our HELLO_ACK
    heartbeats: int = 0         #: RIG_HEARTBEAT frames accepted
    faults: int = 0             #: FAULT frames accepted
    drives_sent: int = 0        #: DRIVE frames written in full
    drives_not_sent: int = 0    #: DRIVE commands the port did not take (down, or full): the rig never got them
    write_errors: int = 0       #: frames the port did not take in full (the rig drops the remainder)
    disconnects: int = 0        #: the port failed or closed under us
    reconnects: int = 0         #: sessions re-established after a disconnect
    handshake_failures: int = 0  #: HELLO without a HELLO_ACK in time, or a version the rig refused
    hellos_repeated: int = 0    #: HELLOs said again after HELLO_REPEAT_S without an answer
    rig_restarts: int = 0       #: sessions re-opened because every frame looked old for RESTART_SILENCE_S


@dataclasses.dataclass(frozen=True)
class Sample:
    """The newest measurement: the message, its frame seq, the host's clock at arrival [s] and a
    running count of measurements received (to tell a new sample from the one seen before)."""

    measurement: Measurement
    seq: int
    arrival_s: float
    count: int


class RigLink:
    """A session with the rig over ``url`` (see the module docstring).

    Parameters
    ----------
    url : str
        Anything ``serial.serial_for_url`` opens: a device or pty path, ``socket://host:port``, ``loop://``.
    baudrate : int
        Line rate (ignored by ptys and sockets).
    connect_timeout_s : float
        How long :meth:`open` (and each reconnection) waits for the rig's HELLO_ACK [s] (at most LONGEST_WAIT_S).
    reconnect : bool
        Reopen the port after a failure.
    reconnect_interval_s : float
        Time between reconnection attempts [s].
    reader_thread : bool
        Poll from a daemon thread (True), or leave :meth:`poll` to the owner (False).
    clock : callable
        The host clock for arrival times (default ``time.perf_counter``).
    on_sample : callable, optional
        ``on_sample(sample)`` for every measurement of the session, in order (by the thread that polls): for an
        owner that records the whole stream, where :meth:`latest` keeps only the newest.
    """

    def __init__(self, url: str, *, baudrate: int = 2_000_000, connect_timeout_s: float = 2.0, reconnect: bool = True,
                 reconnect_interval_s: float = 0.05, reader_thread: bool = True,
                 clock: Callable[[], float] = time.perf_counter,
                 on_sample: Callable[[Sample], None] | None = None) -> None:
        if not isinstance(url, str) or not url.strip():
            raise LinkError("no port given: set the URL of the rig's serial port (a device path, a pty, socket://...)")
        self.url = url.strip()
        self.baudrate = int(require_positive("baudrate", baudrate))
        self.connect_timeout_s = require_duration("connect_timeout_s", connect_timeout_s, LONGEST_WAIT_S)
        self.reconnect = bool(reconnect)
        self.reconnect_interval_s = require_duration("reconnect_interval_s", reconnect_interval_s, LONGEST_WAIT_S)
        self.reader_thread = bool(reader_thread)
        self.clock = clock
        self.on_sample = on_sample
        self.decoder = FrameDecoder(RIG_TO_HOST)
        self.counters = LinkCounters()
        self.faults: collections.deque[Fault] = collections.deque(maxlen=FAULT_HISTORY)
        self.rig: HelloAck | None = None
        self.rig_status = 0
        self.rig_frames_dropped = 0
        self.drive_gaps = GapStats()  # host time between DRIVE frames leaving: the margin to the rig's watchdog
        self.last_error = ""
        self._encoder = FrameEncoder()
        self._port: serial.SerialBase | None = None
        self._latest: Sample | None = None
        self._lock = threading.Lock()      # guards _latest
        self._write_lock = threading.Lock()  # guards _port writes and the encoder
        self._acknowledged = threading.Event()
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None
        self._refused: Fault | None = None
        self._hello_at = 0.0      # when this session's first HELLO went out
        self._hello_again_at = 0.0  # when to repeat it if no HELLO_ACK has come
        self._heard_at = 0.0        # when the decoder last accepted a frame
        self._hellos_said = 0       # HELLOs of this session (more than one: the rig may restart its count twice)
        self._drove = False         # a DRIVE has gone out in this session (the rig's watchdog is armed)
        self.last_drive_seq: int | None = None  # the frame seq of the last DRIVE sent
        self._reconnect_at = 0.0
        self._lost_reason = ""
        self._opening: concurrent.futures.Future | None = None  # a port being opened for a polling owner

    # --- the session -------------------------------------------------------------------------------
    def open(self) -> HelloAck:
        """Open the port, say HELLO and wait for the rig's HELLO_ACK (and start the reader thread, if
        ``reader_thread``). Raises LinkError."""
        if self._thread is not None and not self._thread.is_alive():
            self._thread = None  # the reader of an earlier session, ended
        if self._port is not None or self._thread is not None:
            raise LinkError(f"{self.url}: the link is already open (or its reader is still closing)")
        self._stopping.clear()
        self._refused = None  # kept across the reader's reconnections while open() waits
        failures = self.counters.handshake_failures
        self._connect()  # raises on failure: nothing is left running
        if self.reader_thread:
            self._thread = threading.Thread(target=self._read_loop, name=f"nfal-rig-link {self.url}", daemon=True)
            self._thread.start()
        # the reader reconnects by itself if the port fails meanwhile; an owner that polls stops waiting then
        self.wait_until(lambda: self._acknowledged.is_set() or self._refused is not None
                        or (not self.reader_thread and self._port is None), self.connect_timeout_s)
        if not self._acknowledged.is_set():
            refused = self._refused
            self.close()
            if self.counters.handshake_failures == failures:  # not counted yet by the poll that gave up
                self.counters.handshake_failures += 1
            if refused is not None:
                raise LinkError(f"{self.url}: the rig refused protocol version {PROTOCOL_VERSION} "
                                f"(FAULT VERSION_MISMATCH, detail {refused.detail:g})")
            raise LinkError(f"{self.url}: no HELLO_ACK from the rig within {self.connect_timeout_s:g} s "
                            "(is the rig or `nfal rig-emulator` running on this port, speaking nfal protocol "
                            f"{PROTOCOL_VERSION}?)")
        return self.rig

    @property
    def connected(self) -> bool:
        """A session is up: the port is open and the rig has answered HELLO."""
        return self._port is not None and self._acknowledged.is_set()

    @property
    def descriptor(self) -> int | None:
        """The open port's file descriptor (None when down, or for a port that has none, such as ``loop://``)."""
        return serial_descriptor(self._port)

    @property
    def next_frame_seq(self) -> int:
        """The seq the next frame this link sends takes: a loop that writes DRIVE frames on :attr:`descriptor` itself
        (the compiled loop) continues from here and sets it back, so that STOP follows its last DRIVE in order."""
        return self._encoder.next_seq

    @next_frame_seq.setter
    def next_frame_seq(self, seq: int) -> None:
        with self._write_lock:
            self._encoder.next_seq = int(seq) % (1 << 32)

    def wait_until(self, condition: Callable[[], bool], timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` for ``condition()``, polling every WAIT_PAUSE_S if there is no reader
        thread (for set-up: a co-simulation step never waits). Returns ``condition()``'s last value."""
        deadline = self.clock() + timeout_s
        while True:
            if not self.reader_thread:
                self.poll()
            if condition():
                return True
            if self.clock() >= deadline:
                return False
            time.sleep(WAIT_PAUSE_S if not self.reader_thread else READ_TIMEOUT_S / 10)

    def wait_readable(self, timeout_s: float) -> None:
        """Return when the port has bytes to read or after ``timeout_s`` (:func:`wait_readable`)."""
        wait_readable(serial_descriptor(self._port), timeout_s)

    def latest(self) -> Sample | None:
        """The newest measurement (None before the first)."""
        with self._lock:
            return self._latest

    def send_drive(self, voltage: float) -> bool:
        """Write DRIVE(voltage) without waiting; False if the port is down or did not take the whole frame.

        The session's first DRIVE arms the rig's watchdog, so an owner that polls first takes in the stream's backlog
        (every measurement since HELLO_ACK, undecoded while it set up: up to ~25 us a frame): the second DRIVE then
        follows the first as promptly as any other."""
        if not self._drove and not self.reader_thread:
            self.drain()
        if self._send(Drive(float(voltage))):
            self._drove = True
            self.last_drive_seq = self._encoder.last_seq
            self.counters.drives_sent += 1
            self.drive_gaps.mark(self.clock())
            return True
        self.counters.drives_not_sent += 1
        return False

    def wait_applied(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` for a measurement that reports the last DRIVE applied (it carries that DRIVE's seq):
        the answer of a rig in lockstep, or the next sample of one on its own clock. True if it came."""
        deadline = self.clock() + timeout_s
        while True:
            self.poll()
            latest = self._latest
            if latest is not None and latest.measurement.command_seq == self.last_drive_seq:
                return True
            remaining = deadline - self.clock()
            if remaining <= 0 or self._port is None:
                return False
            self.wait_readable(remaining)

    def drain(self) -> None:
        """Poll until the port has nothing waiting (at most a few DRAIN_LIMIT reads: a rig streams on meanwhile)."""
        for _ in range(8):
            self.poll()
            port = self._port
            try:
                if port is None or not port.in_waiting:
                    return
            except READ_ERRORS:
                return  # the next poll notices the failure

    def close(self, *, stop: bool = True) -> None:
        """Send STOP (if ``stop`` and connected), stop the reader and close the port."""
        if stop and self.connected:
            self._send(Stop())
        self._stopping.set()
        port = self._port
        if port is not None:
            try:
                port.cancel_read()
            except Exception:  # noqa: BLE001 - not every port type can cancel; the read times out anyway
                pass
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)  # a reader inside a slow socket:// connect ends when that does
        if self._thread is not None and not self._thread.is_alive():
            self._thread = None
        opening, self._opening = self._opening, None
        if opening is not None:  # a port opened after close() is closed at once
            opening.add_done_callback(lambda done: done.exception() is None and done.result().close())
        self._close_port()

    def health(self) -> dict:
        """Every counter (link and decoder), the rig's dropped-frame count and the last error, for reports."""
        return {**dataclasses.asdict(self.counters), **self.decoder.counters.as_dict(),
                "rig_frames_dropped": self.rig_frames_dropped, "connected": self.connected,
                "last_error": self.last_error, "drive_gaps": self.drive_gaps.report()}

    def __enter__(self) -> "RigLink":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- the port ----------------------------------------------------------------------------------
    def _connect(self) -> None:
        """Open the port and say HELLO (the reader takes the HELLO_ACK)."""
        self._start_session(self._open_port())

    def _open_port(self) -> serial.SerialBase:
        # the reader thread waits for the first byte; an owner that polls never waits (timeout 0)
        return open_port(self.url, self.baudrate, READ_TIMEOUT_S if self.reader_thread else 0)

    def _start_session(self, port: serial.SerialBase) -> None:
        """Make ``port`` the link's and say HELLO on it (unless the link is closing: then close it)."""
        with self._write_lock:
            if self._stopping.is_set():  # close() came while the port was being opened
                port.close()
                raise LinkError(f"{self.url}: the link was closed")
            self._port = port
        if not self._handshake():
            self._close_port()
            raise LinkError(f"{self.url}: could not write HELLO")

    def _handshake(self) -> bool:
        """A new session on the port: forget the acknowledgement and the rig's count, and say HELLO."""
        self._acknowledged.clear()
        self.decoder.reset_sequence()
        self._hello_at, self._hellos_said, self._drove = self.clock(), 0, False
        return self._say_hello()

    def _say_hello(self) -> bool:
        """HELLO at seq 0, after a 0x00 that ends whatever partial frame the rig may hold (spec 2.1)."""
        self._hello_again_at = self.clock() + HELLO_REPEAT_S
        self._hellos_said += 1
        with self._write_lock:  # one piece: no DRIVE may take seq 0 before it
            self._encoder.restart()
            return self._write(DELIMITER) and self._write(self._encoder(Hello(PROTOCOL_VERSION)))

    def _send(self, message) -> bool:
        with self._write_lock:
            return self._write(self._encoder(message))

    def _write(self, frame: bytes) -> bool:
        """Write ``frame`` without waiting (the write lock held); False if the port did not take all of it."""
        port = self._port
        if port is None:
            return False
        try:
            written = port.write(frame)
        except serial.SerialTimeoutException:
            written = 0  # the port took none of it in time
        except (serial.SerialException, OSError) as exc:
            self._lost(port, _failed("write failed", exc))
            return False
        if written is not None and written != len(frame):
            self.counters.write_errors += 1
            return False
        return True

    def _close_port(self) -> None:
        with self._write_lock:
            port, self._port = self._port, None
        self._acknowledged.clear()
        if port is not None:
            try:
                port.close()
            except Exception:  # noqa: BLE001 - closing a port that already failed
                pass

    def _lost(self, port, reason: str) -> None:
        """``port`` failed: record why, once; the reader reconnects (if allowed)."""
        if self._stopping.is_set() or port is not self._port:
            return  # closing, or already handled (a write and a read failed on the same port)
        self.last_error = self._lost_reason = reason
        self._port = None
        self._acknowledged.clear()
        self.counters.disconnects += 1  # after the state: a thread that sees the count sees the link down
        logger.warning("%s: link lost: %s", self.url, reason)
        if port is not None:
            try:
                port.close()
            except Exception:  # noqa: BLE001
                pass

    # --- reading --------------------------------------------------------------------------------------
    def poll(self, *, block: bool = False) -> None:
        """Take in what the port holds: decode it, keep the newest measurement, the faults and the rig's
        status; reconnect when due. ``block``: wait up to READ_TIMEOUT_S for the first byte (the reader
        thread); otherwise return at once. Only one thread may poll (the reader, when it runs)."""
        port = self._port
        if port is None:
            self._reconnect_if_due()
            return
        try:
            if block:  # up to READ_TIMEOUT_S for the first byte, then what is waiting
                data = port.read(max(1, port.in_waiting))
            else:  # the port was opened with timeout 0: what has arrived
                data = chunk = port.read(READ_CHUNK)
                # a large chunk is a backlog (the host stalled): read on until the port runs dry, so that the newest
                # sample is the newest sent (a tty hands over at most 4095 bytes a read; in_waiting lags behind)
                while len(chunk) >= BACKLOG_BYTES and len(data) < DRAIN_LIMIT:
                    chunk = port.read(READ_CHUNK)
                    data += chunk
        except READ_ERRORS as exc:
            self._lost(port, _failed("read failed", exc))
            return
        if data:
            self._handle(data)
        if not self._acknowledged.is_set():  # what came has been read: is the answer to HELLO still missing?
            now = self.clock()
            if now - self._hello_at > self.connect_timeout_s:
                self.counters.handshake_failures += 1
                self._lost(port, f"no HELLO_ACK within {self.connect_timeout_s:g} s")
            elif now >= self._hello_again_at and self._refused is None:  # lost on the wire? (spec 6)
                self.counters.hellos_repeated += 1
                self._say_hello()

    def _reconnect_if_due(self) -> None:
        if self._opening is not None:
            self._finish_opening()
            return
        now = self.clock()
        if not self.reconnect or self._stopping.is_set() or now < self._reconnect_at:
            return
        self._reconnect_at = now + self.reconnect_interval_s
        if self.reader_thread:  # the reader may wait for the port
            try:
                self._connect()
            except LinkError as exc:
                self._reopen_failed(exc)
            return
        self._opening = concurrent.futures.Future()  # an owner's poll may not: a daemon thread opens it
        threading.Thread(target=_resolve, args=(self._opening, self._open_port), daemon=True,
                         name=f"nfal-rig-open {self.url}").start()

    def _finish_opening(self) -> None:
        """Say HELLO on the port the opener thread opened, once it has (or note why it could not)."""
        opening = self._opening
        if not opening.done():
            return
        self._opening = None
        try:
            self._start_session(opening.result())
        except Exception as exc:  # noqa: BLE001 - a step must not fail for a reopening that did: it is tried again
            self._reopen_failed(exc)

    def _reopen_failed(self, exc: Exception) -> None:
        self.last_error = f"{self._lost_reason}; reopening: {exc}"

    def _read_loop(self) -> None:
        while not self._stopping.is_set():
            if self._port is None and not self.reconnect:
                return
            if self._port is None:
                self._stopping.wait(max(0.0, min(self.reconnect_interval_s, self._reconnect_at - self.clock())))
            self.poll(block=True)

    def _handle(self, data: bytes) -> None:
        now = self.clock()
        stale_before = self.decoder.counters.out_of_order
        accepted = self.decoder.feed(data)
        if accepted:
            self._heard_at = now
        elif self.decoder.counters.out_of_order > stale_before and self._acknowledged.is_set():
            if self._hellos_said > 1:
                # the rig also answered a repeated HELLO, restarting its count, and that HELLO_ACK was lost: follow it
                self._hellos_said = 1
                self.decoder.reset_sequence()
            elif now - self._heard_at > RESTART_SILENCE_S:
                self._rig_restarted()
        for received in accepted:
            message = received.message
            if isinstance(message, Measurement):
                if not self._acknowledged.is_set():  # still the session before ours (a reconnection's HELLO in flight)
                    self.counters.measurements_before_session += 1
                    continue
                self.counters.measurements += 1
                self.rig_status = message.status
                sample = Sample(message, received.seq, now, self.counters.measurements)
                with self._lock:
                    self._latest = sample
                if self.on_sample is not None:
                    self.on_sample(sample)
            elif isinstance(message, RigHeartbeat):
                self.counters.heartbeats += 1
                self.rig_status, self.rig_frames_dropped = message.status, message.frames_dropped
            elif isinstance(message, HelloAck):
                self._hello_ack(message)
            elif isinstance(message, Fault):
                self.counters.faults += 1
                self.faults.append(message)
                logger.warning("%s: rig fault %s (detail %g) at rig time %.6f s", self.url,
                               _fault_name(message.code), message.detail, message.timestamp_us * 1e-6)
                if message.code == FaultCode.VERSION_MISMATCH:
                    self._refused = message

    def _rig_restarted(self) -> None:
        """Only frames that look old for RESTART_SILENCE_S: a rig that restarted counts from 0 again without a
        HELLO_ACK (spec 3), so say HELLO again."""
        self.counters.rig_restarts += 1
        logger.warning("%s: the rig's frames all look old (it restarted?): saying HELLO again", self.url)
        self._handshake()

    def _hello_ack(self, ack: HelloAck) -> None:
        if self._acknowledged.is_set():
            return  # a repeated HELLO_ACK (duplicated on the wire) opens nothing new
        if ack.protocol_version != PROTOCOL_VERSION:
            self.counters.handshake_failures += 1
            self.last_error = f"the rig speaks protocol version {ack.protocol_version}, not {PROTOCOL_VERSION}"
            self._refused = Fault(0, FaultCode.VERSION_MISMATCH, float(ack.protocol_version))
            return
        if self.rig is not None:
            self.counters.reconnects += 1
            logger.warning("%s: session re-established", self.url)
        self.rig = ack
        self._acknowledged.set()


def serial_descriptor(port: serial.SerialBase | None) -> int | None:
    """The file descriptor under a pyserial port (None for none, or a URL without one, e.g. ``loop://``)."""
    try:
        return port.fileno() if port is not None else None
    except (AttributeError, *READ_ERRORS):
        return None


def wait_readable(descriptor: int | None, timeout_s: float) -> None:
    """Return when ``descriptor`` has bytes to read or after ``timeout_s`` (select: one wake-up per arrival, where
    sleeping in short pauses wakes many times for nothing); without a descriptor, sleep WAIT_PAUSE_S."""
    if descriptor is None:
        time.sleep(min(timeout_s, WAIT_PAUSE_S))
        return
    try:
        select.select([descriptor], [], [], max(0.0, timeout_s))
    except (OSError, ValueError):  # closed under us: the next read notices
        pass


def _failed(what: str, exc: BaseException) -> str:
    """``what: reason``, without saying ``what`` twice (pyserial's messages often start with it)."""
    reason = str(exc) or type(exc).__name__
    return reason if reason.startswith(what) else f"{what}: {reason}"


def _resolve(future: concurrent.futures.Future, function: Callable) -> None:
    """Run ``function`` and put its result or its exception in ``future`` (on a helper thread)."""
    try:
        future.set_result(function())
    except Exception as exc:  # noqa: BLE001 - handed to the poll that takes the result
        future.set_exception(exc)


def _fault_name(code: int) -> str:
    try:
        return FaultCode(code).name
    except ValueError:
        return f"code {code}"
