"""The C reference firmware's numbers for docs/firmware.md: size, tick cost, and the plant channel's round trip.

    python bench/bench_firmware.py

1. The Cortex-M4F build's flash and RAM (``arm-none-eabi-size``).
2. Its tick in QEMU mps2-an386 with ``-icount shift=3`` (8 ns per instruction: 125 MIPS, about a 168 MHz
   Cortex-M4 at 1.3 cycles per instruction): 2000 ticks of a session at the emulator's 2 kHz with a DRIVE
   every tick (heartbeats every 200), measured by the firmware with SysTick, without the wait for the sensors.
3. The host build's tick (ns, clock_gettime) on the same script.
4. The wall time of one tick through the plant channel (begin + end: what the emulator pays per tick) for the
   host build (pipes) and QEMU (a Unix socket into UART1, no -icount), 2000 ticks each.
"""

from __future__ import annotations

import subprocess
import time

import numpy as np
from machine import describe

from nfal.hil.firmware import RigReading, RigTiming
from nfal.hil.plant_channel import ExternalFirmware, FirmwareProcess, build
from nfal.hil.protocol import PROTOCOL_VERSION, Drive, FrameEncoder, Hello

TICKS = 2000
READING = RigReading(1e-4, 28_500.0, True, False)


def session(process: FirmwareProcess) -> tuple[np.ndarray, np.ndarray]:
    """(tick cost [ns] as the firmware counts it, wall time of the tick through the channel [s])."""
    firmware = ExternalFirmware(process, RigTiming())
    host = FrameEncoder()
    walls = []
    for k in range(TICKS):
        data = host(Hello(PROTOCOL_VERSION)) if k == 0 else host(Drive(60.0))
        start = time.perf_counter()
        firmware.receive(data, k)
        firmware.report(k, READING)
        walls.append(time.perf_counter() - start)
    return np.array([process.cost_ns(c) for c in firmware.costs[1:]]), np.array(walls[1:])


def stats(values: np.ndarray, scale: float, unit: str) -> str:
    p50, p99 = np.percentile(values, [50, 99])
    return f"median {p50 * scale:.1f} {unit}, p99 {p99 * scale:.1f} {unit}, max {values.max() * scale:.1f} {unit}"


def main() -> None:
    print(describe())
    elf = build("mps2")
    print(subprocess.run(["arm-none-eabi-size", str(elf)], capture_output=True, text=True, check=True).stdout)
    with FirmwareProcess("qemu", icount_shift=3) as process:
        cost, _ = session(process)
    print(f"QEMU -icount shift=3 tick: {stats(cost, 1e-3, 'us')}; instructions {stats(cost / 8, 1, '')}")
    with FirmwareProcess("c") as process:
        cost, wall = session(process)
    print(f"host build tick: {stats(cost, 1e-3, 'us')}; through the plant channel (pipes): {stats(wall, 1e6, 'us')}")
    with FirmwareProcess("qemu") as process:
        _, wall = session(process)
    print(f"QEMU through the plant channel (UART1, no -icount): {stats(wall, 1e6, 'us')}")


if __name__ == "__main__":
    main()
