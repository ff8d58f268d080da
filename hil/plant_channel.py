"""The C reference firmware (``firmware/``) behind the emulator: build it, start it, and talk to it.

The firmware's hardware abstraction is served, in emulation, over a **plant channel**
(``firmware/plant/nfal_plant.h`` has the records): the emulator paces the ticks and plays the rig's
hardware with its own truth, exactly as for :class:`~nfal.hil.firmware.Firmware`. Each tick:

1. ``'T'`` starts the tick (in tunnel mode with the host's bytes); the firmware takes the host's frames,
   decides the voltage and asks for it to be applied: ``'D'`` (its ``hal_drive_write``);
2. the emulator applies it to the truth and answers with the sensors: ``'S'`` (``hal_sensor_read``);
3. the firmware sends its frames to the host and ends the tick: ``'E'`` (cost, status, applied voltage,
   command_seq; in tunnel mode the rig's bytes).

Two firmwares, same sources: ``"c"``, the host build (a Linux process; plant channel on its stdin and
stdout), and ``"qemu"``, the Cortex-M4F build in ``qemu-system-arm -M mps2-an386`` (plant channel on
UART1, through a Unix socket). The protocol goes either on the firmware's own serial line (the host
build's pty, QEMU's UART0 on ``-serial pty``: ``serial=True``) or through the plant channel (tunnel mode:
exact tick by tick, for the conformance tests).

:class:`ExternalFirmware` has :class:`~nfal.hil.firmware.Firmware`'s interface (``receive``, ``voltage``,
``report``), so the emulator's tick loop and the protocol tests run it unchanged.
"""

from __future__ import annotations

import dataclasses
import fcntl
import os
import select
import shutil
import socket
import struct
import subprocess
import tempfile
import time
import types
from pathlib import Path

from nfal.errors import FirmwareBuildError, InvalidParameterError, LinkError

from .firmware import RigReading, RigTiming
from .protocol import DecoderCounters, Measurement, StatusFlags

#: The firmware sources (a source checkout: ``pip install -e .``).
FIRMWARE_DIR = Path(__file__).resolve().parent.parent / "firmware"
#: The rig firmwares the emulator can run: the Python one, the C host build, the C build in QEMU.
FIRMWARES = ("python", "c", "qemu")
#: The Makefile's targets and what each builds: the firmware as a Linux process, its C unit tests, the firmware for
#: QEMU's board, the host's compiled loop (a shared library).
BUILDS = {"host": "nfal-fw-host", "test": "test_core", "mps2": "nfal-fw-mps2.elf", "loop": "libnfal-loop.so"}
#: What each build needs: (program, Debian package).
NEEDS = {"host": (("make", "make"), ("cc", "gcc")),
         "mps2": (("make", "make"), ("arm-none-eabi-gcc", "gcc-arm-none-eabi")),
         "qemu": (("qemu-system-arm", "qemu-system-arm"),)}
#: The QEMU board: Cortex-M4F with CMSDK UARTs (UART0: protocol, UART1: plant channel).
QEMU_MACHINE = "mps2-an386"
#: Longest wait for one answer of the firmware [s] (QEMU starting up included).
ANSWER_TIMEOUT_S = 10.0
#: Most host bytes one tick carries in tunnel mode (the firmware's TUNNEL_BYTES).
TUNNEL_BYTES = 2048
#: The QEMU SysTick clock on mps2 (25 MHz): one count is 40 ns of the guest's virtual time.
QEMU_SYSTICK_NS = 40

_CONFIG = struct.Struct("<IIIIfB")
_SENSOR = struct.Struct("<ffB")
_END = struct.Struct("<IHfIBH")
_COUNTERS = struct.Struct("<13I")
_COUNTER_NAMES = ("frames_ok", "cobs_errors", "crc_errors", "truncated", "oversized", "unknown_type", "invalid_value",
                  "out_of_order", "lost")


def require_tools(build: str) -> None:
    """Raise FirmwareBuildError naming the Debian package of each program ``build`` needs and lacks."""
    missing = [f"{program} (Debian package {package})" for program, package in NEEDS[build]
               if not shutil.which(program)]
    if missing:
        raise FirmwareBuildError(f"the {build} build of the reference firmware needs {', '.join(missing)}: "
                                 f"apt-get install {' '.join(p for _, p in NEEDS[build])}")


def build(target: str, build_dir: str | os.PathLike | None = None) -> Path:
    """Build ``target`` with firmware/Makefile; return the program, ELF or library (:data:`BUILDS`)."""
    if target not in BUILDS:
        raise InvalidParameterError("firmware target", target, ", ".join(BUILDS))
    if not (FIRMWARE_DIR / "Makefile").exists():
        raise FirmwareBuildError(f"no firmware sources at {FIRMWARE_DIR} (an installed nfal without its source tree)")
    require_tools("mps2" if target == "mps2" else "host")
    out = Path(build_dir) if build_dir is not None else FIRMWARE_DIR / "build"
    out.mkdir(parents=True, exist_ok=True)
    # one make at a time per folder: two emulators (or test workers) starting together must not write one ELF at once
    with open(out / ".build.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        done = subprocess.run(["make", "-s", "-C", str(FIRMWARE_DIR), f"BUILD={out.resolve()}", target],
                              capture_output=True, text=True)
    if done.returncode != 0:
        text = done.stderr + done.stdout
        hint = " (is libnewlib-arm-none-eabi installed?)" if "nano.specs" in text or "newlib" in text else ""
        raise FirmwareBuildError(f"make {target} failed{hint}:\n{text.strip()}")
    return out.resolve() / BUILDS[target]


@dataclasses.dataclass(frozen=True)
class TickEnd:
    """The firmware's 'E' record: what one tick did."""

    cost: int           #: the tick's own work in the platform's counter (ns on the host, SysTick counts in QEMU)
    status: int         #: the status word (with the reading's flags)
    applied: float      #: the voltage applied over the period [V]
    command_seq: int
    armed: bool         #: a DRIVE has armed the watchdog (and no STOP or HELLO after a trip disarmed it)
    rig_bytes: bytes    #: tunnel mode: the frames for the host


class PlantChannel:
    """The emulator's end of the plant channel: records over a pair of file descriptors (see the module docstring)."""

    def __init__(self, read_fd: int, write_fd: int, process: subprocess.Popen, name: str) -> None:
        self.read_fd, self.write_fd, self.process, self.name = read_fd, write_fd, process, name
        self._buffer = bytearray()

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(self.write_fd, view):]
            except BrokenPipeError:
                raise LinkError(f"the {self.name} firmware stopped (exit status {self.process.poll()})") from None

    def _read(self, n: int) -> bytes:
        deadline = None
        while len(self._buffer) < n:
            ready, _, _ = select.select([self.read_fd], [], [], 0.5)
            if ready:
                chunk = os.read(self.read_fd, 65536)
                if not chunk:
                    raise LinkError(f"the {self.name} firmware stopped (exit status {self.process.poll()})")
                self._buffer += chunk
                continue
            deadline = deadline or time.monotonic() + ANSWER_TIMEOUT_S
            if self.process.poll() is not None or time.monotonic() > deadline:
                raise LinkError(f"the {self.name} firmware does not answer on its plant channel "
                                f"(exit status {self.process.poll()})")
        data = bytes(self._buffer[:n])
        del self._buffer[:n]
        return data

    def _expect(self, code: bytes, size: int) -> bytes:
        record = self._read(1 + size)
        if record[:1] != code:
            raise LinkError(f"the {self.name} firmware sent {record[:1]!r} on its plant channel, not {code!r}")
        return record[1:]

    def configure(self, timing: RigTiming, tunnel: bool) -> None:
        """Reset the firmware to power-up with ``timing`` (a reboot: all state cleared)."""
        self._write(b"C" + _CONFIG.pack(round(timing.sample_period_s * 1e6), round(timing.watchdog_timeout_s * 1e6),
                                        round(timing.ramp_down_s * 1e6), round(timing.heartbeat_period_s * 1e6),
                                        timing.max_drive_voltage, int(tunnel)))
        if self._expect(b"R", 1) != b"\x01":
            raise InvalidParameterError("firmware timing", timing, "one the C firmware takes (whole microseconds)")

    def begin(self, host_bytes: bytes = b"") -> float:
        """Start a tick (with the host's bytes in tunnel mode); return the voltage the firmware applies [V]."""
        if len(host_bytes) > TUNNEL_BYTES:
            raise InvalidParameterError("host bytes in one tick", len(host_bytes), f"<= {TUNNEL_BYTES}")
        self._write(b"T" + struct.pack("<H", len(host_bytes)) + host_bytes)
        return struct.unpack("<f", self._expect(b"D", 4))[0]

    def end(self, reading: RigReading) -> TickEnd:
        """Answer the firmware's sensor read with ``reading``; return the end of the tick."""
        self._write(b"S" + _SENSOR.pack(reading.height, reading.drive_frequency,
                                        int(bool(reading.locked)) | int(bool(reading.resting)) << 1))
        cost, status, applied, command_seq, state, n = _END.unpack(self._expect(b"E", _END.size))
        return TickEnd(cost, status, applied, command_seq, bool(state & 1), self._read(n) if n else b"")

    def counters(self) -> dict[str, int]:
        """The firmware's receive counters, with rx_overflow, tx_dropped, cost_max and tx_frames (since configured)."""
        self._write(b"K")
        values = _COUNTERS.unpack(self._expect(b"k", _COUNTERS.size))
        return dict(zip((*_COUNTER_NAMES, "rx_overflow", "tx_dropped", "cost_max", "tx_frames"), values))


class FirmwareProcess:
    """A running C firmware: ``kind`` "c" (host build) or "qemu" (mps2-an386), with its plant channel.

    Parameters
    ----------
    kind : "c" or "qemu"
    serial : bool
        The protocol on the firmware's own serial line (a pty: :attr:`serial_path`); else tunnel mode only.
    icount_shift : int, optional
        QEMU only: ``-icount shift=N`` (every guest instruction takes 2^N ns of the guest's time), for the tick
        cost in instructions.
    build_dir : path-like, optional
    """

    def __init__(self, kind: str, *, serial: bool = False, icount_shift: int | None = None,
                 build_dir: str | os.PathLike | None = None) -> None:
        if kind not in ("c", "qemu"):
            raise InvalidParameterError("firmware", kind, "c or qemu")
        self.kind, self.icount_shift = kind, icount_shift
        self.serial_path: str | None = None
        self._socket = self._folder = self._holder = None
        if kind == "c":
            program = build("host", build_dir)
            self.process = subprocess.Popen([str(program), *(["--pty"] if serial else [])], stdin=subprocess.PIPE,
                                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
            self.channel = PlantChannel(self.process.stdout.fileno(), self.process.stdin.fileno(), self.process, "C")
            if serial:
                self.serial_path = self._announced(self.process.stderr, "pty ")
        else:
            require_tools("qemu")
            elf = build("mps2", build_dir)
            self._folder = tempfile.TemporaryDirectory(prefix="nfal-fw-qemu-")
            path = os.path.join(self._folder.name, "plant.sock")
            server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            server.bind(path)
            server.listen(1)
            icount = [] if icount_shift is None else ["-icount", f"shift={int(icount_shift)}"]
            self.process = subprocess.Popen(
                ["qemu-system-arm", "-M", QEMU_MACHINE, "-display", "none", "-monitor", "none",
                 "-serial", "pty" if serial else "null", "-chardev", f"socket,id=plant,path={path}",
                 "-serial", "chardev:plant", "-kernel", str(elf), *icount],
                stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
            try:
                self._socket = self._accept(server)
            except OSError:
                exited = self.process.poll() is not None
                reason = self.process.stderr.read().decode(errors="replace").strip() if exited else "timed out"
                self.close()
                raise LinkError(f"qemu-system-arm did not connect to the plant channel: {reason}") from None
            finally:
                server.close()
            self.channel = PlantChannel(self._socket.fileno(), self._socket.fileno(), self.process, "QEMU")
            if serial:  # QEMU says "char device redirected to /dev/pts/N (label serial0)" on stdout
                self.serial_path = self._announced(self.process.stdout, "char device redirected to ").split()[0]
                # held open here (never read), as the host build and PtyPort hold theirs: QEMU's pty is then always
                # connected, and a host that goes and comes back finds the rig streaming (QEMU polls a closed pty
                # for a reader only once a second)
                self._holder = os.open(self.serial_path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)

    def _accept(self, server: socket.socket) -> socket.socket:
        """QEMU's connection to the plant channel; OSError if QEMU exits first or takes ANSWER_TIMEOUT_S."""
        server.settimeout(0.1)
        deadline = time.monotonic() + ANSWER_TIMEOUT_S
        while self.process.poll() is None and time.monotonic() < deadline:
            try:
                connection, _ = server.accept()
            except socket.timeout:
                continue
            connection.settimeout(None)
            return connection
        raise OSError("QEMU did not connect")

    def _announced(self, stream, prefix: str) -> str:
        ready, _, _ = select.select([stream], [], [], ANSWER_TIMEOUT_S)
        line = stream.readline().decode(errors="replace").strip() if ready else ""
        if not line.startswith(prefix):
            self.close()
            raise LinkError(f"the {self.kind} firmware did not announce its serial port (said {line!r})")
        return line[len(prefix):]

    def cost_ns(self, cost: int) -> float:
        """A tick cost as the firmware counts it, in ns (of the guest's virtual time for QEMU)."""
        return float(cost) * (QEMU_SYSTICK_NS if self.kind == "qemu" else 1.0)

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
        self.process.wait()
        for stream in (self.process.stdin, self.process.stdout, self.process.stderr):
            if stream is not None:
                stream.close()
        if self._socket is not None:
            self._socket.close()
        if self._holder is not None:
            os.close(self._holder)
            self._holder = None
        if self._folder is not None:
            self._folder.cleanup()

    def __enter__(self) -> "FirmwareProcess":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class ExternalFirmware:
    """:class:`~nfal.hil.firmware.Firmware`'s interface over a :class:`FirmwareProcess` (reconfigured: a reboot).

    In tunnel mode the host's bytes go in through :meth:`receive` and the rig's frames come out of
    :meth:`report`; otherwise the firmware has its own serial line, :meth:`receive` takes no bytes and
    :meth:`report` returns none.
    """

    def __init__(self, process: FirmwareProcess, timing: RigTiming = RigTiming(), *, tunnel: bool = True) -> None:
        self.process, self.timing, self.tunnel = process, timing, tunnel
        self.channel = process.channel
        self.channel.configure(timing, tunnel)
        self.applied = 0.0
        self.session = self.armed = False
        self.command_seq = 0
        self.last_measurement: Measurement | None = None
        self.costs: list[int] = []
        self.on_event = lambda t, text: None  # on_event(rig_time_s, text), as Firmware's (set by the Emulator)
        self._period_us = round(timing.sample_period_s * 1e6)
        self._status = 0
        self.host_bytes_dropped = 0  #: host bytes beyond what a tick carries (tunnel mode)

    def receive(self, data: bytes, tick: int) -> list[bytes]:
        if data and not self.tunnel:
            raise InvalidParameterError("host bytes", len(data), "none: this firmware reads its own serial line")
        if len(data) > TUNNEL_BYTES:  # more than a tick's line carries (a host's flood): the oldest are lost, as in
            lost = len(data) - TUNNEL_BYTES  # a UART's overrun, and the firmware resynchronises at the next frame
            self.host_bytes_dropped += lost
            self.on_event(tick * self._period_us * 1e-6, f"{lost} bytes from the host lost: more than the "
                          f"{TUNNEL_BYTES} a tick carries")
            data = data[-TUNNEL_BYTES:]
        self.applied = self.channel.begin(bytes(data))
        return []

    def voltage(self, tick: int) -> tuple[float, list[bytes]]:
        return self.applied, []

    def report(self, tick: int, reading: RigReading) -> list[bytes]:
        end = self.channel.end(reading)
        self.costs.append(end.cost)
        self.applied, self.command_seq, self.armed = end.applied, end.command_seq, end.armed
        self.session = bool(end.status & StatusFlags.SESSION_ACTIVE)
        self._events(tick, end.status)
        if self.session:
            self.last_measurement = Measurement(tick * self._period_us, reading.height, reading.drive_frequency,
                                                end.applied, end.status, end.command_seq)
        return [frame + b"\x00" for frame in end.rig_bytes.split(b"\x00")[:-1]]

    def _events(self, tick: int, status: int) -> None:
        """What a rig would log, from the status word's changes (the C firmware has no printf)."""
        changed, self._status = status ^ self._status, status
        now = tick * self.timing.sample_period_s
        if changed & StatusFlags.SESSION_ACTIVE:
            self.on_event(now, "session open" if status & StatusFlags.SESSION_ACTIVE else "session ended (STOP), drive "
                          "ramping down")
        if changed & StatusFlags.WATCHDOG_TRIPPED and status & StatusFlags.WATCHDOG_TRIPPED:
            self.on_event(now, f"watchdog: no DRIVE for {self.timing.watchdog_timeout_s * 1e3:g} ms, drive ramping "
                          f"down over {self.timing.ramp_down_s * 1e3:g} ms")
        if changed & StatusFlags.DRIVE_LIMITED and status & StatusFlags.DRIVE_LIMITED:
            self.on_event(now, f"DRIVE above {self.timing.max_drive_voltage:g} V: clamped")

    @property
    def decoder(self):
        """Like :class:`~nfal.hil.protocol.FrameDecoder`: ``.counters`` (asked of the firmware now)."""
        counters = self.channel.counters()
        return types.SimpleNamespace(counters=DecoderCounters(**{name: counters[name] for name in _COUNTER_NAMES}))


class FirmwarePort:
    """The port of a firmware with its own serial line, for the emulator: a stable symlink at ``path`` to the
    firmware's pty (as :class:`~nfal.hil.ports.PtyPort` makes one); the bytes never pass through Python."""

    def __init__(self, process: FirmwareProcess, path: str | os.PathLike | None = None) -> None:
        from .ports import _require_free_link_path  # here: ports imports pyserial, which the FMU side never needs

        if process.serial_path is None:
            raise InvalidParameterError("firmware process", process.kind, "one started with serial=True")
        if path is None:
            handle, path = tempfile.mkstemp(prefix="nfal-rig-")
            os.close(handle)
            os.unlink(path)
        self.process, self.path = process, Path(path)
        _require_free_link_path(self.path)
        temporary = self.path.with_name(f".{self.path.name}.{os.getpid()}.new")
        try:
            temporary.unlink(missing_ok=True)
            os.symlink(process.serial_path, temporary)
            os.replace(temporary, self.path)
        except OSError as exc:
            raise LinkError(f"cannot make the port's link {self.path}: {exc.strerror or exc}") from None
        self.failures, self.last_error, self.connected = 0, "", True

    @property
    def bytes_dropped(self) -> int:
        """Bytes the firmware could not queue for the host (its TX queue full)."""
        return self.process.channel.counters()["tx_dropped"] if self.process.process.poll() is None else 0

    def read(self) -> bytes:
        return b""

    def write(self, data: bytes, *, wait_s: float = 0.0) -> None:
        if data:
            raise InvalidParameterError("bytes for the host", len(data), "none: the firmware writes its own line")

    def connect(self) -> None:
        self.connected = True

    def disconnect(self) -> None:
        self.connected = False

    def close(self) -> None:
        self.path.unlink(missing_ok=True)
