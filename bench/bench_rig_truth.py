"""The emulated rig's cost per 0.5 ms tick: the slow truth against the Reynolds truth, in the same run.

    python bench/bench_rig_truth.py

Each built-in rig structure (rig_slow, rig_reynolds: ``nfal rig-emulator --truth slow|reynolds``) is run
in-process as the emulator runs it (:func:`nfal.apps.rig_model.open_rig`) for 10 s of rig time from rest
(45 V, lift-off, then 60 V), twice, the second time with the imports, numba kernels and the Reynolds
plant's film table warm; rig_slow warm at 0 V, the object resting on the surface all along (an emulator's state while
no host drives it); then rig_slow once more through the co-simulation master (:class:`StructureRig`, the
path of a rig structure that is not all nfal FMUs). Per tick: ``reading`` + ``advance``, in wall time and in
this thread's CPU time. A tick whose wall time exceeds the 500 us period but whose CPU time does not was the
machine's (the thread was not running: another process, the hypervisor); a tick whose CPU time exceeds it is
the rig model's own overrun; the plant's share is timed on its own (its ``do_step``, CPU time).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import record

from nfal.apps.build import build_all
from nfal.apps.rig_model import StructureRig, open_rig

TICK_S = 5e-4
TICKS = 20000
#: The row of the slow truth at rest on the surface.
RESTING = "rig_slow, resting (0 V)"


def timed(step, costs: list):
    """``step`` (a slave's do_step) appending its CPU time [s] to ``costs`` at each call."""
    def wrapper(*args):
        started = time.thread_time()
        try:
            return step(*args)
        finally:
            costs.append(time.thread_time() - started)
    return wrapper


def tick_costs(rig, voltages: tuple[float, ...] = (45.0, 60.0)) -> tuple[np.ndarray, np.ndarray]:
    """Wall and CPU time [us] of each of TICKS ticks (``reading`` + ``advance``), ``voltages`` [V] in turn, each for
    an equal share of them."""
    costs, cpu = np.empty(TICKS), np.empty(TICKS)
    for k in range(TICKS):
        rig.apply(voltages[k * len(voltages) // TICKS])
        tick, tick_cpu = time.perf_counter(), time.thread_time()
        rig.reading()
        rig.advance()
        costs[k], cpu[k] = time.perf_counter() - tick, time.thread_time() - tick_cpu
    return costs * 1e6, cpu * 1e6


def summary(name: str, run: int, setup: float, costs: np.ndarray, cpu: np.ndarray, plant: np.ndarray | None) -> dict:
    """One row: set-up [s], and of the ticks' wall and CPU times and the plant's doStep CPU time [us]: mean, p99,
    max and how many exceed the 500 us tick."""
    def stats(values: np.ndarray | None) -> dict | None:
        if values is None:
            return None
        return {"mean_us": round(float(values.mean()), 1), "p99_us": round(float(np.percentile(values, 99)), 1),
                "max_us": round(float(values.max()), 1), "over_500_us": int(np.sum(values > 500))}
    return {"truth": name, "run": run, "setup_s": round(setup, 3), "tick": stats(costs), "tick_cpu": stats(cpu),
            "plant_cpu": stats(plant)}


def measured(path: Path, voltages: tuple[float, ...] = (45.0, 60.0)) -> tuple:
    """Set-up time [s], the ticks' wall and CPU times [us] and the plant's doStep CPU times [us] of the rig structure
    at ``path`` run in-process (:func:`tick_costs`)."""
    started = time.perf_counter()
    with open_rig(path, TICK_S) as rig:
        setup = time.perf_counter() - started
        plant = []
        rig.plant.do_step = timed(rig.plant.do_step, plant)  # the in-process rig's Plant slave
        costs, cpu = tick_costs(rig, voltages)
    return setup, costs, cpu, np.array(plant) * 1e6


def main() -> None:
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        paths = build_all(Path(folder), structures=("rig_slow", "rig_reynolds"))
        for run in (1, 2):
            for name in ("rig_slow", "rig_reynolds"):
                rows.append(summary(name, run, *measured(paths[name])))
                print(rows[-1], flush=True)
        rows.append(summary(RESTING, 2, *measured(paths["rig_slow"], (0.0,))))
        started = time.perf_counter()  # the same rig through the co-simulation master (a user's structure's path)
        with StructureRig(paths["rig_slow"], TICK_S) as rig:
            setup = time.perf_counter() - started
            costs, cpu = tick_costs(rig)
        rows.append(summary("rig_slow through the master", 2, setup, costs, cpu, None))
    result = {"ticks": TICKS, "rows": rows}
    print(record.save("rig-truth", result))
    record.show(tables(result), findings(result))


def tables(result: dict) -> list[record.Table]:
    def cells(stats: dict | None, p99: bool = True) -> list:
        if stats is None:
            return ["-"] * (4 if p99 else 3)
        return [f"{stats['mean_us']:.0f}", *([f"{stats['p99_us']:.0f}"] if p99 else []), f"{stats['max_us']:.0f}",
                stats["over_500_us"]]
    return [record.Table(f"{result['ticks']} ticks of 0.5 ms each (10 s of rig time):",
                         ["truth", "run", "set-up [s]", "tick mean [µs]", "p99 [µs]", "max [µs]", "ticks > 500 µs",
                          "CPU per tick: mean [µs]", "max [µs]", "ticks > 500 µs of CPU",
                          "Plant doStep CPU: mean [µs]", "max [µs]", "> 500 µs"],
                         [[row["truth"], row["run"], f"{row['setup_s']:.2f}", *cells(row["tick"]),
                           *cells(row["tick_cpu"], p99=False), *cells(row["plant_cpu"], p99=False)]
                          for row in result["rows"]])]


def findings(result: dict) -> list[str]:
    warm = {row["truth"]: row for row in result["rows"] if row["run"] == 2}
    slow, reynolds = warm["rig_slow"], warm["rig_reynolds"]
    return [f"Warm (run 2), the slow truth's tick costs {slow['tick']['mean_us'] / reynolds['tick']['mean_us']:.2f}x "
            f"the Reynolds truth's (the baseline, same run) and its plant "
            f"{slow['plant_cpu']['mean_us'] / reynolds['plant_cpu']['mean_us']:.2f}x; a tick over 500 µs of wall "
            "time whose CPU time is not was the machine's, not the model's."] + \
        ([f"Resting on the surface (0 V, warm), the slow truth's tick costs "
          f"{warm[RESTING]['tick_cpu']['mean_us'] / slow['tick_cpu']['mean_us']:.2f}x its tick lifting the object "
          f"and its plant {warm[RESTING]['plant_cpu']['mean_us'] / slow['plant_cpu']['mean_us']:.2f}x (CPU time, "
          "same run)."] if RESTING in warm else [])

if __name__ == "__main__":
    main()
