"""The emulator's end of the wire: a pseudo-terminal (:class:`PtyPort`) or any pyserial URL (:class:`UrlPort`).

Both read and write without blocking (a byte the host has no room for is dropped and counted: a rig
does not wait for its host; the next write starts with a frame delimiter, so that only the cut frame is lost, not the
next one glued to its head) and can be disconnected and reconnected, as a USB cable is pulled and
plugged back. A pty is reached through a stable symlink (like ``/dev/serial/by-id/...``) that points
at a new pty after each reconnection, so the host reopens the same path.
"""

from __future__ import annotations

import fcntl
import os
import struct
import tempfile
import termios
import time
import tty
from pathlib import Path

import serial

from nfal.errors import LinkError

from .link import READ_ERRORS, open_port, serial_descriptor, wait_readable
from .protocol import DELIMITER

#: Most bytes one read takes.
READ_CHUNK = 65536
#: How often a write that waits for room tries again [s] (a pty master selects writable when full too).
ROOM_POLL_S = 0.0005


def _require_free_link_path(path: Path) -> None:
    if not os.path.lexists(path):
        return
    if path.is_symlink() and os.readlink(path).startswith("/dev/pts/") and not path.exists():
        return  # a stale link of a pty that is gone: an earlier emulator's
    raise LinkError(f"--link {path}: something is there already; give a path that does not exist (the emulator "
                    "puts a symlink there and removes it at exit)")


class _Writer:
    """The ports' write: what the host has room for, the rest dropped and counted."""

    bytes_dropped: int  # including a delimiter put before the next frame after a cut
    connected: bool
    _cut = False  # the last write cut a frame: the host's decoder holds its head

    def write(self, data: bytes, *, wait_s: float = 0.0) -> None:
        """Write what the host has room for; with ``wait_s``, wait up to that long for room for the rest (a rig in
        lockstep, whose host waits for every answer); drop and count what is left."""
        if not self.connected or not data:
            return
        # after a cut frame, a delimiter first: the host then drops that frame alone (back-to-back delimiters are
        # idle fill), where it would glue the next one to its head and drop both
        data = (DELIMITER if self._cut else b"") + data
        written, deadline = self._write_some(data), time.monotonic() + wait_s
        while written < len(data) and self.connected and time.monotonic() < deadline:
            time.sleep(ROOM_POLL_S)
            written += self._write_some(data[written:])
        if written:
            self._cut = written < len(data)
        self.bytes_dropped += len(data) - written

    def _write_some(self, data: bytes) -> int:
        """Write what fits now, without waiting; the number of bytes written."""
        raise NotImplementedError


class PtyPort(_Writer):
    """A pty whose other end the host opens at :attr:`path` (a symlink to the current ``/dev/pts/N``).

    Parameters
    ----------
    path : path-like, optional
        Where to put the symlink; default a new name in the temporary folder. Refused (LinkError) if
        something is there already, other than a pty link an earlier emulator left behind: the symlink is
        removed at exit, and a user's file must not be.
    """

    def __init__(self, path: str | os.PathLike | None = None) -> None:
        if path is None:
            handle, name = tempfile.mkstemp(prefix="nfal-rig-")
            os.close(handle)
            os.unlink(name)
            path = name
        self.path = Path(path)
        _require_free_link_path(self.path)
        self.bytes_dropped = 0
        self.failures, self.last_error = 0, ""  # the master side of a pty does not fail (UrlPort's may)
        self._master = self._slave = None
        self.connect()

    @property
    def connected(self) -> bool:
        return self._master is not None

    def connect(self) -> None:
        """Open a new pty (raw, non-blocking) and point :attr:`path` at it. Raises LinkError."""
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line editing: a byte pipe, as pyserial would set it anyway
        os.set_blocking(master, False)
        temporary = self.path.with_name(f".{self.path.name}.{os.getpid()}.new")
        try:
            temporary.unlink(missing_ok=True)
            os.symlink(os.ttyname(slave), temporary)
            os.replace(temporary, self.path)
        except OSError as exc:
            os.close(master)
            os.close(slave)
            raise LinkError(f"cannot make the port's link {self.path}: {exc.strerror or exc}") from None
        # the slave stays open here too: writes never fail for want of a reader
        self._master, self._slave = master, slave

    def disconnect(self) -> None:
        """Close the pty (the host's reads fail) and remove the symlink (its reopen attempts fail)."""
        self.path.unlink(missing_ok=True)
        for fd in (self._master, self._slave):
            if fd is not None:
                os.close(fd)
        self._master = self._slave = None

    def read(self) -> bytes:
        """What the host has sent, without waiting. A tty read that finds nothing first waits for the kernel worker
        that moves bytes received into it, a thread of normal priority that a real-time rig would wait behind: an empty
        pty (FIONREAD) is not read, and bytes on their way are taken at the next tick (nfal_loop.c does the same)."""
        if self._master is None:
            return b""
        try:
            if not struct.unpack("i", fcntl.ioctl(self._master, termios.FIONREAD, b"\0\0\0\0"))[0]:
                return b""
            return os.read(self._master, 65536)
        except (BlockingIOError, InterruptedError):
            return b""

    def wait_readable(self, timeout_s: float) -> None:
        """Return when the host has sent something or after ``timeout_s``."""
        wait_readable(self._master, timeout_s)

    def _write_some(self, data: bytes) -> int:
        try:
            return os.write(self._master, data)
        except (BlockingIOError, InterruptedError):
            return 0

    def close(self) -> None:
        self.disconnect()


class UrlPort(_Writer):
    """Any ``serial.serial_for_url`` URL (a device wired to the host's, ``socket://host:port``, ...)."""

    def __init__(self, url: str, baudrate: int = 2_000_000) -> None:
        self.path, self.baudrate = url, baudrate
        self.bytes_dropped = 0
        self.failures = 0
        self.last_error = ""
        self._port: serial.SerialBase | None = None
        self.connect()

    @property
    def connected(self) -> bool:
        return self._port is not None

    def connect(self) -> None:
        """Open the URL (a ``socket://`` connect may take pyserial up to 5 s). Raises LinkError."""
        self._port = open_port(self.path, self.baudrate, 0)

    def disconnect(self) -> None:
        if self._port is not None:
            self._port.close()
        self._port = None

    def read(self) -> bytes:
        if self._port is None:
            return b""
        try:
            return self._port.read(READ_CHUNK)  # timeout 0: what has arrived (a socket's in_waiting says 1)
        except READ_ERRORS as exc:
            self._failed(exc)
            return b""

    def wait_readable(self, timeout_s: float) -> None:
        """Return when the host has sent something or after ``timeout_s``."""
        wait_readable(serial_descriptor(self._port), timeout_s)

    def _write_some(self, data: bytes) -> int:
        try:
            return self._port.write(data) or 0
        except serial.SerialTimeoutException:
            return 0
        except (serial.SerialException, OSError) as exc:
            self._failed(exc)
            return 0

    def _failed(self, exc: Exception) -> None:
        """The far end went away (a socket closed, a device unplugged): the port is down until :meth:`connect`."""
        self.failures += 1
        self.last_error = str(exc)
        self.disconnect()

    def close(self) -> None:
        self.disconnect()
