"""The C reference firmware (firmware/): its C unit tests, its Cortex-M4F build's size and tick cost, and the
protocol on its own serial line (the host build's pty, QEMU's UART0) against the host's RigLink.

The protocol rules themselves are checked tick by tick against all three firmwares in tests/test_hil_firmware.py;
here the serial path is exercised end to end. Watchdog and ramp are judged in rig time (tick counts the
firmware reports), never in wall-clock windows. A missing tool (make, gcc, gcc-arm-none-eabi,
libnewlib-arm-none-eabi, qemu-system-arm) fails with FirmwareBuildError naming its Debian package.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time

import pytest
from helpers.warm_nfal import popen

from nfal.hil.firmware import RigReading, RigTiming
from nfal.hil.link import RigLink
from nfal.hil.plant_channel import (ExternalFirmware, FirmwareProcess, build, require_tools)
from nfal.hil.protocol import PROTOCOL_VERSION, Drive, FrameEncoder, Hello, HelloAck, StatusFlags

pytestmark = pytest.mark.realtime  # on the wall clock: one at a time, on one worker (conftest.py)

READING = RigReading(1e-4, 28_500.0, True, False)
#: The serial tests' rig: 1 ms ticks, a watchdog of 500 ticks (a reconnecting host has 0.5 s of rig time), a ramp
#: of 50 ticks.
SERIAL_TIMING = RigTiming(sample_period_s=1e-3, watchdog_timeout_s=0.5, ramp_down_s=0.05, max_drive_voltage=150.0,
                          heartbeat_period_s=0.1)
WATCHDOG_TICKS, RAMP_TICKS = 500, 50
#: Generous bound on waits for the rig [s] (wall clock: only to give up, never to judge).
WAIT_S = 20.0


def test_the_c_unit_tests_pass():
    program = build("test")
    done = subprocess.run([str(program)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert "7 tests passed" in done.stdout


def test_a_missing_tool_fails_naming_its_debian_package(monkeypatch):
    from nfal.errors import FirmwareBuildError
    from nfal.hil import plant_channel

    monkeypatch.setattr(plant_channel.shutil, "which", lambda program: None)
    with pytest.raises(FirmwareBuildError, match="gcc-arm-none-eabi"):
        require_tools("mps2")
    with pytest.raises(FirmwareBuildError, match="apt-get install qemu-system-arm"):
        require_tools("qemu")


def test_a_qemu_that_cannot_start_fails_with_its_reason(monkeypatch):
    from nfal.errors import LinkError
    from nfal.hil import plant_channel

    monkeypatch.setattr(plant_channel, "QEMU_MACHINE", "no-such-board")
    with pytest.raises(LinkError, match="unsupported machine"):
        FirmwareProcess("qemu")


def test_the_microcontroller_build_fits_a_small_cortex_m4():
    elf = build("mps2")
    require_tools("mps2")
    done = subprocess.run(["arm-none-eabi-size", "-A", str(elf)], capture_output=True, text=True, check=True)
    sizes = {line.split()[0]: int(line.split()[1]) for line in done.stdout.splitlines()[2:] if len(line.split()) >= 2
             and line.split()[1].isdigit()}
    flash = sizes[".text"] + sizes.get(".ARM.exidx", 0) + sizes.get(".data", 0)
    ram = sizes.get(".data", 0) + sizes[".bss"] + sizes[".stack"]
    assert flash < 16 * 1024 and ram < 16 * 1024, sizes


def test_the_tick_fits_in_half_a_millisecond_in_qemu_counting_instructions():
    """-icount shift=3: every instruction takes 8 ns of the guest's time (125 MIPS, about a 168 MHz Cortex-M4 at
    1.3 cycles per instruction). A session at the emulator's 2 kHz with a DRIVE every tick, heartbeats, a clamp
    fault and a damaged frame; the tick's own work (without the wait for the emulator's sensors) is measured
    by the firmware with SysTick. One tick takes a full RX queue (the most one tick can have to decode)."""
    timing = RigTiming()
    with FirmwareProcess("qemu", icount_shift=3) as process:
        firmware = ExternalFirmware(process, timing)
        host = FrameEncoder()
        for k in range(600):
            data = host(Hello(PROTOCOL_VERSION)) if k == 0 else host(Drive(200.0 if k == 300 else 60.0))
            if k == 400:
                data = data[:-3] + b"\x01\x01\x00"  # damaged: a BAD_FRAME fault this tick
            if k == 500:  # the worst case: the MCU build's 256-byte RX queue full (17 DRIVEs, 2.5 ticks at 2 Mbaud)
                data = b"".join(host(Drive(60.0)) for _ in range(17))
            firmware.receive(data, k)
            firmware.report(k, READING)
        costs_ns = sorted(process.cost_ns(c) for c in firmware.costs[1:])
        instructions = [c / 8 for c in costs_ns]
        print(f"\nQEMU mps2-an386 tick, -icount shift=3: median {costs_ns[len(costs_ns) // 2] / 1e3:.1f} us, "
              f"max {costs_ns[-1] / 1e3:.1f} us ({instructions[len(instructions) // 2]:.0f} / {instructions[-1]:.0f} "
              "instructions)")
    assert costs_ns[-1] < 500e3
    assert costs_ns[0] > 0  # the counter runs


class Ticker:
    """Ticks an :class:`ExternalFirmware` with its own serial line about every sample period (wall clock, only for
    pace) and records each tick: (tick, applied voltage, status, command_seq)."""

    def __init__(self, process: FirmwareProcess, timing: RigTiming = SERIAL_TIMING) -> None:
        self.firmware = ExternalFirmware(process, timing, tunnel=False)
        self.period = timing.sample_period_s
        self.records: list[tuple[int, float, int, int]] = []
        self.lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        firmware, k, due = self.firmware, 0, time.monotonic()
        while not self._stop.is_set():
            firmware.receive(b"", k)
            firmware.report(k, READING)
            with self.lock:
                self.records.append((k, firmware.applied, firmware._status, firmware.command_seq))
            k += 1
            due = max(due + self.period, time.monotonic() - 0.05)
            time.sleep(max(0.0, due - time.monotonic()))

    def wait_for(self, condition, what: str) -> tuple[int, float, int, int]:
        deadline = time.monotonic() + WAIT_S
        seen = 0
        while time.monotonic() < deadline:
            with self.lock:
                fresh = self.records[seen:]
            for record in fresh:
                if condition(record):
                    return record
            seen += len(fresh)
            time.sleep(0.005)
        raise AssertionError(f"the rig never {what}")

    def close(self) -> None:
        self._stop.set()
        self._thread.join()


#: QEMU on its serial line. It failed in 2 of 4 runs of this file and in 2 of 3 full-suite runs until the mps2 firmware
#: read its plant channel's UART with the RX interrupt unmasked (a duplicated byte; firmware/mps2/main_mps2.c); after:
#: 16 of 16 serial-line cases passed in 4 runs beside a CPU-bound process.
QEMU_SERIAL = "qemu"


@pytest.fixture(params=["c", QEMU_SERIAL])
def serial_rig(request):
    """(the firmware process with its own serial line, a :class:`Ticker` on it with ``timing``)."""
    with FirmwareProcess(request.param, serial=True) as process:
        tickers = []

        def start(timing: RigTiming = SERIAL_TIMING) -> Ticker:
            tickers.append(Ticker(process, timing))
            return tickers[-1]
        try:
            yield process, start
        finally:
            for ticker in tickers:
                ticker.close()


HOST_SCRIPT = """
import sys, time
from nfal.hil.link import RigLink
link = RigLink(sys.argv[1], connect_timeout_s=10.0)
link.open()
print("driving", flush=True)
while True:
    link.send_drive(80.0)
    time.sleep(0.004)
"""


def test_a_host_on_the_serial_line_gets_hello_ack_and_drives(serial_rig):
    process, start = serial_rig
    ticker = start()
    link = RigLink(process.serial_path, connect_timeout_s=10.0)
    try:
        assert link.open() == HelloAck(1, 1000, 500_000, 50_000, 150.0)
        link.send_drive(60.0)
        ticker.wait_for(lambda r: r[1] == 60.0 and r[2] & StatusFlags.SESSION_ACTIVE, "applied the DRIVE")
        assert link.wait_until(lambda: (s := link.latest()) is not None and s.measurement.drive_voltage == 60.0, WAIT_S)
    finally:
        link.close()


def test_a_killed_host_leaves_the_rig_ramping_to_0_within_watchdog_plus_ramp_in_rig_time(serial_rig):
    process, start = serial_rig
    ticker = start()
    host = subprocess.Popen([sys.executable, "-c", HOST_SCRIPT, process.serial_path], stdout=subprocess.PIPE)
    try:
        assert host.stdout.readline().strip() == b"driving"
        ticker.wait_for(lambda r: r[1] == 80.0, "applied the host's DRIVE")
    finally:
        os.kill(host.pid, signal.SIGKILL)
        host.wait()
    zero = ticker.wait_for(lambda r: r[2] & StatusFlags.WATCHDOG_TRIPPED and r[1] == 0.0, "ramped down to 0 V")
    with ticker.lock:
        records = list(ticker.records)
    last_seq = zero[3]
    last_drive = next(r[0] for r in records if r[3] == last_seq)  # the tick the last DRIVE was applied
    trip = next(r[0] for r in records if r[2] & StatusFlags.WATCHDOG_TRIPPED)
    assert trip == last_drive + WATCHDOG_TICKS
    assert zero[0] - last_drive == WATCHDOG_TICKS + RAMP_TICKS  # V0 (1 - j / ramp) reaches 0 at j = ramp
    assert all(r[1] == 80.0 for r in records if last_drive <= r[0] < trip)


def test_a_host_that_reconnects_within_the_watchdog_time_takes_over_without_a_trip(serial_rig):
    """The rig's watchdog here is 20 s of rig time: a busy machine cannot stretch a reconnection that long (the rule
    itself, tick by tick, is in tests/test_hil_firmware.py)."""
    process, start = serial_rig
    ticker = start(RigTiming(sample_period_s=1e-3, watchdog_timeout_s=20.0, ramp_down_s=0.05, max_drive_voltage=150.0,
                             heartbeat_period_s=0.1))
    first = RigLink(process.serial_path, connect_timeout_s=10.0)
    first.open()
    first.send_drive(70.0)
    ticker.wait_for(lambda r: r[1] == 70.0, "applied the first host's DRIVE")
    first.close(stop=False)  # gone without STOP: the drive stays in force, the watchdog counts
    with RigLink(process.serial_path, connect_timeout_s=10.0) as second:
        second.send_drive(75.0)
        taken = ticker.wait_for(lambda r: r[1] == 75.0, "applied the second host's DRIVE")
    with ticker.lock:
        records = list(ticker.records)
    assert not any(r[2] & StatusFlags.WATCHDOG_TRIPPED for r in records if r[0] <= taken[0])
    assert [r[1] for r in records if r[0] <= taken[0] and r[1] not in (0.0, 70.0, 75.0)] == []


# --- nfal rig-emulator --firmware c|qemu ------------------------------------------------------------------------

@pytest.mark.parametrize("options", [("--drop", "0.1"), ("--disconnect-at", "1"), ("--port", "socket://localhost:1")])
def test_the_emulator_refuses_what_the_c_firmware_cannot_do(options, capsys):
    from nfal.cli import main

    assert main(["rig-emulator", "--firmware", "c", *options]) == 2
    error = capsys.readouterr().err
    assert "error: " in error and ("pty with --firmware c or qemu" in error or "python when faults" in error)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["c", QEMU_SERIAL])
def test_the_emulator_with_the_c_firmware_prints_its_port_and_serves_a_host(fig7_archives, tmp_path, kind):
    """`nfal rig-emulator --firmware c|qemu`: the first line is a port a RigLink opens; the truth answers (the
    height the host measures is the rig_slow sensor's, at rest); the exit summary counts the ticks."""
    link_path = tmp_path / "rig"
    emulator = popen([sys.executable, "-m", "nfal", "rig-emulator",
                      "--truth", str(fig7_archives["rig_slow"]),
                      "--firmware", kind, "--link", str(link_path), "--watchdog", "0.5", "--duration", "60",
                      "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert emulator.stdout.readline().strip() == str(link_path)
        assert "C firmware" in emulator.stdout.readline()
        link = RigLink(str(link_path), connect_timeout_s=10.0)
        try:
            ack = link.open()
            assert (ack.sample_period_us, ack.watchdog_timeout_us, ack.max_drive_voltage) == (500, 500_000, 150.0)
            assert link.wait_until(lambda: link.latest() is not None, WAIT_S)
            assert 0.0 < link.latest().measurement.height < 50e-6  # the object at rest on the surface
        finally:
            link.close()
    finally:
        emulator.terminate()
        output, errors = emulator.communicate(timeout=30)
    assert emulator.returncode == 0, errors
    assert "session open" in output
    report = json.loads(output[output.index("{"):])
    assert report["ticks"] > 0 and report["decoder"]["frames_ok"] >= 1  # the HELLO (the STOP may come after the end)
    assert report["frames_sent"] > 0  # counted by the firmware, which wrote them on its own line
