"""This machine's floor for a 2 kHz loop: what any host of the rig, in any language, gets here (docs/hil.md).

    python bench/machine_floor.py [--seconds 60] [--work-us 0 50]

A C loop (bench/c/machine_floor.c) that does nothing but ``--work-us`` of busy work a step is released every 0.5 ms
as nfal's RealTimePacer releases steps (absolute release times; a late step is not skipped), waiting in nanosleep
(``sleep``) or spinning on the clock (``spin``, work 0 only: the vCPU never idles; under SCHED_FIFO the kernel's
real-time throttling then stops it 50 ms a second). It runs at normal priority and under SCHED_FIFO 50 (as root),
idle and with a CPU-bound process beside it (``python -c "while True: pass"``). Its overruns (steps that finish
after the next one's release, RealTimePacer's count) and its longest gap between two step starts are the least a
host can show on this machine: a number in docs/hil.md below this floor is the machine's, not the code's. Writes
bench/results/machine-floor.json, with the hypervisor's steal over each run (the share of the vCPUs it took).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import record
from machine import describe

from nfal.realtime import steal_s
from realtime import neighbour

HERE = Path(__file__).resolve().parent
SOURCE = HERE / "c" / "machine_floor.c"


def build(folder: Path) -> Path:
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        sys.exit("machine_floor: no C compiler (apt-get install gcc)")
    binary = folder / "machine_floor"
    subprocess.run([compiler, "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", str(SOURCE), "-o", str(binary)],
                   check=True)
    return binary


def measure(binary: Path, seconds: float, work_us: float, fifo: bool, wait: str) -> dict:
    command = [str(binary), str(seconds), str(work_us), wait]
    if fifo:
        command = ["chrt", "-f", "50", *command]
    stolen = steal_s()
    done = subprocess.run(command, capture_output=True, text=True, check=True)
    steal = None if stolen is None else round(100 * (steal_s() - stolen) / (seconds * os.cpu_count()), 3)
    return {**json.loads(done.stdout), "steal_percent": steal}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="length of each run (default 60)")
    parser.add_argument("--work-us", type=float, nargs="+", default=[0.0, 50.0],
                        help="busy work a step [us] (default 0 and 50)")
    args = parser.parse_args()
    print(describe(), flush=True)
    priorities = [False, True] if os.geteuid() == 0 else [False]
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        binary = build(Path(folder))
        for busy in (False, True):
            with neighbour(busy):
                for fifo in priorities:
                    for wait, work in [("sleep", work) for work in args.work_us] + [("spin", 0.0)]:
                        row = {"neighbour": busy, "priority": "SCHED_FIFO 50" if fifo else "normal", "wait": wait,
                               "work_us": work, **measure(binary, args.seconds, work, fifo, wait)}
                        print(json.dumps(row), flush=True)
                        rows.append(row)
    path = record.save("machine-floor", {"seconds": args.seconds, "runs": rows})
    print(path, flush=True)


def tables(result: dict) -> list[record.Table]:
    return [record.Table(f"Each run {result['seconds']:g} s of 0.5 ms steps:",
                         ["CPU-bound process beside", "priority", "wait", "work a step [µs]", "overruns [%]",
                          "longest gap between step starts [ms]", "gaps > 5 ms", "gaps > 10 ms",
                          "hypervisor's steal [%]"],
                         [["yes" if run["neighbour"] else "no", run["priority"], run["wait"], f"{run['work_us']:g}",
                           f"{run['overrun_share_percent']:.2f}", f"{run['gap_max_ms']:.1f}", run["gaps_over_5ms"],
                           run["gaps_over_10ms"], run.get("steal_percent", "-")] for run in result["runs"]])]


def findings(result: dict) -> list[str]:
    runs = result["runs"]
    best = min(runs, key=lambda run: run["overrun_share_percent"])
    return [f"Overruns {min(r['overrun_share_percent'] for r in runs):.2f}-"
            f"{max(r['overrun_share_percent'] for r in runs):.1f} % of steps, the longest gap "
            f"{min(r['gap_max_ms'] for r in runs):.1f}-{max(r['gap_max_ms'] for r in runs):.1f} ms over the runs; "
            f"the best: {best['wait']}, {best['priority']}, {'beside' if best['neighbour'] else 'without'} the "
            f"CPU-bound process ({best['overrun_share_percent']:.2f} %, {best['gap_max_ms']:.1f} ms). A host of the "
            "rig on this machine cannot do better than this loop, which does nothing: docs/hil.md, \"This machine's "
            "floor\"."]


if __name__ == "__main__":
    main()
