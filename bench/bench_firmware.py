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
import record

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


def stats(values: np.ndarray, scale: float) -> dict:
    p50, p99 = np.percentile(values, [50, 99])
    return {"median": round(float(p50 * scale), 2), "p99": round(float(p99 * scale), 2),
            "max": round(float(values.max() * scale), 2)}


def main() -> None:
    elf = build("mps2")
    size = subprocess.run(["arm-none-eabi-size", str(elf)], capture_output=True, text=True, check=True).stdout
    names, values = (line.split() for line in size.strip().splitlines()[:2])
    with FirmwareProcess("qemu", icount_shift=3) as process:
        qemu_cost, _ = session(process)
    with FirmwareProcess("c") as process:
        host_cost, host_wall = session(process)
    with FirmwareProcess("qemu") as process:
        _, qemu_wall = session(process)
    result = {"ticks": TICKS, "size": dict(zip(names[:4], map(int, values[:4]))),
              "rows": [{"case": "Cortex-M4F in QEMU mps2-an386, -icount shift=3: the tick [µs]",
                        **stats(qemu_cost, 1e-3)},
                       {"case": "the same, instructions a tick", **stats(qemu_cost / 8, 1)},
                       {"case": "host build: the tick [µs]", **stats(host_cost, 1e-3)},
                       {"case": "host build through the plant channel (pipes): the round trip [µs]",
                        **stats(host_wall, 1e6)},
                       {"case": "QEMU through the plant channel (UART1, no -icount): the round trip [µs]",
                        **stats(qemu_wall, 1e6)}]}
    print(record.save("firmware", result))
    record.show(tables(result), findings(result))


def title(result: dict) -> str:
    return "The C reference firmware: size, tick cost and the plant channel's round trip"


def tables(result: dict) -> list[record.Table]:
    return [record.Table(f"{result['ticks']} ticks of a session at 2 kHz, a DRIVE every tick:",
                         ["case", "median", "p99", "max"],
                         [[row["case"], row["median"], row["p99"], row["max"]] for row in result["rows"]])]


def findings(result: dict) -> list[str]:
    size = result["size"]
    return [f"The Cortex-M4F build (arm-none-eabi-size): text {size['text']} B, data {size['data']} B, bss "
            f"{size['bss']} B: flash {size['text'] + size['data']} B, static RAM {size['data'] + size['bss']} B."]

if __name__ == "__main__":
    main()
