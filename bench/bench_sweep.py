"""Sweep benchmark: a 32-run robustness sweep of the Fig. 7 loop on 1 and on 2 Dask workers. Prints markdown.

    python bench/bench_sweep.py [--stop-time S]

Goal (issue #6): speed-up of 2 workers over 1 >= 1.8x, and the engine's per-task overhead against
the run's own cost. The spec: 4 plant masses (-20 % .. +20 %) x 4 noise seeds x 2 resonance-drift
draws, each run 0.7 s of simulated time at 0.5 ms (one up and one down step of 40 um).

For each worker count a local cluster is started (not timed: "startup"), its workers are warmed up
(a sweep of the same 32 runs cut to 0.1 s: every worker imports nfal, fmpy and the FMUs' slave
modules and caches the archive once: "warm-up", not timed either), then the sweep is timed from the
first submit to the last row written ("sweep"), through the scheduler address so that the timing is
the engine's alone. "overhead per task" = (workers x sweep wall time - sum of the tasks' own wall
times) / runs: scheduling, shipping, result rows, idle tail.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import record

from nfal.apps.build import build_all
from nfal.orchestration.sweep import read_table, run_sweep
from nfal.apps.sweeps import parse_spec


def spec(stop_time: float, name: str = "robustness32"):
    return parse_spec({
        "sweep": {"name": name},
        "run": {"kind": "ssp", "structure": "fig7_slow", "stop_time": stop_time, "step_size": 5e-4,
                "reference": {"levels_m": [100e-6, 140e-6, 100e-6], "hold_s": 0.3, "lead_s": 0.1},
                "ramps": {"ResonanceTracker.resonance_shift": {"initial": 0.0, "start_s": 0.05, "duration_s": 0.5}}},
        "grid": {"Plant.mass": [0.10776, 0.12123, 0.14817, 0.16164], "SensorChain.seed": [0, 1, 2, 3]},
        "random": {"draws": 2, "seed": 6, "inputs.ResonanceTracker.resonance_shift":
                   {"distribution": "uniform", "low": -60.0, "high": 60.0}},
    })


def measure(sweep, archives, workers: int, folder: Path) -> dict:
    from dask.distributed import Client, LocalCluster

    t0 = time.perf_counter()
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
    client = Client(cluster)
    startup = time.perf_counter() - t0
    t0 = time.perf_counter()
    warm_up = spec(0.1, "warm-up")  # 32 short runs: every worker imports and loads the FMUs once
    run_sweep(warm_up, folder / "warm-up", scheduler=cluster.scheduler_address, archives=archives, plot=False)
    warmup = time.perf_counter() - t0
    try:
        result = run_sweep(sweep, folder / "sweep", scheduler=cluster.scheduler_address, archives=archives, plot=False)
    finally:
        client.close()
        cluster.close()
    rows = read_table(result.csv_path)
    task = sum(r["wall_time_s"] for r in rows)
    wall = result.summary["wall_time_s"]
    return {"workers": workers, "startup": startup, "warmup": warmup, "wall": wall, "task_total": task,
            "task_mean": task / len(rows), "overhead": (workers * wall - task) / len(rows), "rows": rows,
            "ok": sum(r["status"] == "ok" for r in rows)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stop-time", type=float, default=0.7)
    args = parser.parse_args()
    sweep = spec(args.stop_time)
    with tempfile.TemporaryDirectory() as tmp:
        archives = build_all(Path(tmp) / "build", structures=("fig7_slow",))
        one, two = (measure(sweep, archives, n, Path(tmp) / f"w{n}") for n in (1, 2))
    same = all(a["iae_m_s"] == b["iae_m_s"] for a, b in zip(one["rows"], two["rows"]))
    keep = ("workers", "startup", "warmup", "wall", "task_total", "task_mean", "overhead", "ok")
    result = {"stop_time_s": args.stop_time, "runs": len(one["rows"]), "tables_identical": same,
              "measurements": [{key: measured[key] for key in keep} for measured in (one, two)]}
    print(record.save("sweep", result))
    record.show(tables(result), findings(result))


def title(result: dict) -> str:
    return "Sweeps: a 32-run robustness sweep on 1 and 2 Dask workers"


def tables(result: dict) -> list[record.Table]:
    return [record.Table(f"{result['runs']} runs of {result['stop_time_s']:g} s (0.5 ms steps) of fig7_slow; the "
                         "cluster's start and a warm-up sweep are not in the sweep's wall time:",
                         ["workers", "startup [s]", "warm-up [s]", "sweep wall [s]", "task mean [s]",
                          "overhead per task [ms]", "ok"],
                         [[m["workers"], f"{m['startup']:.2f}", f"{m['warmup']:.2f}", f"{m['wall']:.2f}",
                           f"{m['task_mean']:.3f}", f"{m['overhead'] * 1e3:.1f}", f"{m['ok']}/{result['runs']}"]
                          for m in result["measurements"]])]


def findings(result: dict) -> list[str]:
    one, two = result["measurements"]
    return [f"Speed-up of 2 workers over 1 (the baseline, same run): {one['wall'] / two['wall']:.2f}x (goal >= 1.8x); "
            f"the two sweeps' tables are {'identical' if result['tables_identical'] else 'NOT identical'}."]


if __name__ == "__main__":
    main()
