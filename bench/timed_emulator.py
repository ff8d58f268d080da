"""``nfal rig-emulator`` with its Plant's doStep timed in CPU time, for bench_hil.py. Same arguments.

    python bench/timed_emulator.py --truth reynolds --json

At exit (also on SIGTERM, which the emulator handles) it writes one line to stderr,
``plant-cpu {"calls": N, "mean_us": ..., "max_us": ..., "over_500_us": ...}``: how long the truth's
plant computed per 0.5 ms tick of the real run (CPU time, so a stall of the machine is not counted).
"""

from __future__ import annotations

import atexit
import json
import sys
import time

from nfal.cli import main
from nfal.fmus.reynolds_plant import ReynoldsPlant
from nfal.fmus.slow_plant import SlowPlant

COSTS: list[float] = []
PREFIX = "plant-cpu "


def timed(step):
    def do_step(self, current_time, step_size):
        started = time.thread_time()
        try:
            return step(self, current_time, step_size)
        finally:
            COSTS.append(time.thread_time() - started)
    return do_step


def report() -> None:
    us = [cost * 1e6 for cost in COSTS] or [0.0]
    summary = {"calls": len(COSTS), "mean_us": sum(us) / len(us), "max_us": max(us),
               "over_500_us": sum(cost > 500 for cost in us)}
    print(PREFIX + json.dumps(summary), file=sys.stderr, flush=True)


def parse(stderr: str) -> dict | None:
    """The summary :func:`report` wrote, from the emulator's stderr (None if there is none)."""
    lines = [line for line in stderr.splitlines() if line.startswith(PREFIX)]
    return json.loads(lines[-1][len(PREFIX):]) if lines else None


if __name__ == "__main__":
    for plant in (ReynoldsPlant, SlowPlant):  # the in-process rig's Plant is one of them
        plant.do_step = timed(plant.do_step)
    atexit.register(report)
    sys.exit(main(["rig-emulator", *sys.argv[1:]]))
