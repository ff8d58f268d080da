"""The emulated rig's cost per 0.5 ms tick: the slow truth against the Reynolds truth, in the same run.

    python bench/bench_rig_truth.py

Each built-in rig structure (rig_slow, rig_reynolds: ``nfal rig-emulator --truth slow|reynolds``) is run
in-process as the emulator runs it (:func:`nfal.rig_model.open_rig`) for 10 s of rig time from rest
(45 V, lift-off, then 60 V), twice, the second time with the imports, numba kernels and the Reynolds
plant's film table warm. Per tick: ``reading`` + ``advance``. A tick that takes longer than 500 us on a
loaded machine is mostly the machine (compare the slow truth's count); the plant's own cost is the mean.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np
from machine import describe

from nfal.build import build_all
from nfal.rig_model import open_rig

TICK_S = 5e-4
TICKS = 20000


def main() -> None:
    print(f"machine: {describe()}; load average {os.getloadavg()[0]:.2f}\n")
    print("| truth | run | set-up [s] | tick mean [us] | p99 [us] | max [us] | ticks > 500 us |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as folder:
        paths = build_all(Path(folder), structures=("rig_slow", "rig_reynolds"))
        for run in (1, 2):
            for name in ("rig_slow", "rig_reynolds"):
                started = time.perf_counter()
                with open_rig(paths[name], TICK_S) as rig:
                    setup = time.perf_counter() - started
                    costs = np.empty(TICKS)
                    for k in range(TICKS):
                        rig.apply(45.0 if k < TICKS // 2 else 60.0)
                        tick = time.perf_counter()
                        rig.reading()
                        rig.advance()
                        costs[k] = time.perf_counter() - tick
                costs *= 1e6
                print(f"| {name} | {run} | {setup:.2f} | {costs.mean():.0f} | {np.percentile(costs, 99):.0f} | "
                      f"{costs.max():.0f} | {int(np.sum(costs > 500))} |")


if __name__ == "__main__":
    main()
