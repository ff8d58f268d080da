"""This machine's floor for a 2 kHz loop: what any host of the rig, in any language, gets here (docs/hil.md).

    python bench/machine_floor.py [--seconds 60] [--work-us 0 50]

A C loop (bench/c/machine_floor.c) that does nothing but ``--work-us`` of busy work a step is released every 0.5 ms
as nfal's RealTimePacer releases steps (absolute release times; a late step is not skipped), waiting in nanosleep
(``sleep``) or spinning on the clock (``spin``, work 0 only: the vCPU never idles; under SCHED_FIFO the kernel's
real-time throttling then stops it 50 ms a second). It runs at normal priority and under SCHED_FIFO 50 (as root),
idle and with a CPU-bound process beside it (``python -c "while True: pass"``). Its overruns (steps that finish
after the next one's release, RealTimePacer's count) and its longest gap between two step starts are the least a
host can show on this machine: a number in docs/hil.md below this floor is the machine's, not the code's. Writes
bench/results/machine-floor.json.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from machine import describe
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
    done = subprocess.run(command, capture_output=True, text=True, check=True)
    return json.loads(done.stdout)


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
    result = {"bench": "machine-floor", "machine": describe(),
              "command": "python bench/machine_floor.py " + " ".join(sys.argv[1:]),
              "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "load_average": os.getloadavg(),
              "seconds": args.seconds, "runs": rows}
    path = HERE / "results" / "machine-floor.json"
    path.parent.mkdir(exist_ok=True)
    path.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    print(path, flush=True)


if __name__ == "__main__":
    main()
