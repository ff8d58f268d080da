"""The emulated rig's cost per 0.5 ms tick: the slow truth against the Reynolds truth, in the same run.

    python bench/bench_rig_truth.py

Each built-in rig structure (rig_slow, rig_reynolds: ``nfal rig-emulator --truth slow|reynolds``) is run
in-process as the emulator runs it (:func:`nfal.apps.rig_model.open_rig`) for 10 s of rig time from rest
(45 V, lift-off, then 60 V), twice, the second time with the imports, numba kernels and the Reynolds
plant's film table warm; then rig_slow once more through the co-simulation master (:class:`StructureRig`, the
path of a rig structure that is not all nfal FMUs). Per tick: ``reading`` + ``advance``, in wall time and in
this thread's CPU time. A tick whose wall time exceeds the 500 us period but whose CPU time does not was the
machine's (the thread was not running: another process, the hypervisor); a tick whose CPU time exceeds it is
the rig model's own overrun; the plant's share is timed on its own (its ``do_step``, CPU time).
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np
from machine import describe

from nfal.apps.build import build_all
from nfal.apps.rig_model import StructureRig, open_rig

TICK_S = 5e-4
TICKS = 20000


def timed(step, costs: list):
    """``step`` (a slave's do_step) appending its CPU time [s] to ``costs`` at each call."""
    def wrapper(*args):
        started = time.thread_time()
        try:
            return step(*args)
        finally:
            costs.append(time.thread_time() - started)
    return wrapper


def tick_costs(rig) -> tuple[np.ndarray, np.ndarray]:
    """Wall and CPU time [us] of each of TICKS ticks (``reading`` + ``advance``), 45 V then 60 V."""
    costs, cpu = np.empty(TICKS), np.empty(TICKS)
    for k in range(TICKS):
        rig.apply(45.0 if k < TICKS // 2 else 60.0)
        tick, tick_cpu = time.perf_counter(), time.thread_time()
        rig.reading()
        rig.advance()
        costs[k], cpu[k] = time.perf_counter() - tick, time.thread_time() - tick_cpu
    return costs * 1e6, cpu * 1e6


def print_row(name: str, run: int, setup: float, costs: np.ndarray, cpu: np.ndarray, plant: np.ndarray | None) -> None:
    plant_columns = ("- | - | -" if plant is None
                     else f"{plant.mean():.0f} | {plant.max():.0f} | {int(np.sum(plant > 500))}")
    print(f"| {name} | {run} | {setup:.2f} | {costs.mean():.0f} | {np.percentile(costs, 99):.0f} | {costs.max():.0f} | "
          f"{int(np.sum(costs > 500))} | {cpu.mean():.0f} | {cpu.max():.0f} | {int(np.sum(cpu > 500))} | "
          f"{plant_columns} |", flush=True)


def main() -> None:
    print(f"machine: {describe()}; load average {os.getloadavg()[0]:.2f}\n")
    print("| truth | run | set-up [s] | tick mean [us] | p99 [us] | max [us] | ticks > 500 us | CPU per tick: mean "
          "[us] | max [us] | ticks > 500 us of CPU | Plant doStep CPU: mean [us] | max [us] | > 500 us |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as folder:
        paths = build_all(Path(folder), structures=("rig_slow", "rig_reynolds"))
        for run in (1, 2):
            for name in ("rig_slow", "rig_reynolds"):
                started = time.perf_counter()
                with open_rig(paths[name], TICK_S) as rig:
                    setup = time.perf_counter() - started
                    plant = []
                    rig.plant.do_step = timed(rig.plant.do_step, plant)  # the in-process rig's Plant slave
                    costs, cpu = tick_costs(rig)
                print_row(name, run, setup, costs, cpu, np.array(plant) * 1e6)
        started = time.perf_counter()  # the same rig through the co-simulation master (a user's structure's path)
        with StructureRig(paths["rig_slow"], TICK_S) as rig:
            setup = time.perf_counter() - started
            costs, cpu = tick_costs(rig)
        print_row("rig_slow through the master", 2, setup, costs, cpu, None)


if __name__ == "__main__":
    main()
