"""The Reynolds loop, fast: harmonic balance against time marching, in the same run. Prints markdown.

    python bench/bench_reynolds.py [--quick]

1. Wall time of ``fig7_reynolds`` (3.7 s of simulated staircase at 0.5 ms, the whole loop as FMUs, set-up
   included) with ``Plant.film_solver`` = harmonic_balance (the default) and = time_marching (the solver
   before issue 16: 41 x 64 BDF2, envelope following), one after the other in this process, each after
   a warm-up run (imports, numba caches); reported as wall time / simulated time and their ratio.
2. Accuracy of the plant: the averaged harmonic-balance plant (``AveragedFilmPlant``, the FMU's default
   table: 41 radial nodes Richardson-extrapolated with 81, 6 harmonics, the free object) against the
   time-marched coupled model converged by Richardson extrapolation of 41 x 64 and 81 x 128, under an
   open-loop |a| staircase (4 -> 6.86 -> 2 um through the transducer's lag, the paper shape, released
   quasi-steady at 60 um): the
   largest relative height error after the first 30 ms, and the 81 x 128 grid's own distance from the
   extrapolation (how converged the reference is).
--quick: 1.0 s of loop, 0.15 s of accuracy run.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from machine import describe

from nfal.build import build_all
from nfal.fig7 import DEFAULT_STAIRCASES
from nfal.models.averaged_plant import AveragedFilmPlant
from nfal.models.coupled import CoupledModel
from nfal.models.excitation import paper_shape
from nfal.models.film_force_table import FilmForceTable
from nfal.models.rig import RigParameters
from nfal.orchestration import run_structure

STEP = 5e-4
SOLVERS = ("harmonic_balance", "time_marching")


def loop_wall_time(archive: Path, solver: str, stop: float, out: Path) -> tuple[float, dict]:
    """Wall time [s] of one fig7_reynolds run as a library call (set-up included), and its summary."""
    started = time.perf_counter()
    result = run_structure(archive, stop_time=stop, step_size=STEP,
                           inputs={"Controller.reference": DEFAULT_STAIRCASES["fig7_reynolds"]}, parameters={"Plant.film_solver": solver}, out_dir=out, plot=False, progress=False)
    return time.perf_counter() - started, result.summary


#: The transducer's time constant Q / (pi f) (Table 2: Q = 500 at 28.5 kHz): |a| follows a drive step with it.
TRANSDUCER_LAG_S = 500 / (np.pi * 28.5e3)


def excitation(t: float) -> float:
    """The open-loop |a| staircase of the accuracy check [m], 4 -> 6.86 -> 2 um at 50 and 100 ms, each step
    smoothed by the transducer's lag as the loop's ResonanceTracker delivers it (an abrupt jump of |a|
    kicks the marched object through its fast oscillation's start-up: up to 1.5e-3 for ~10 ms)."""
    value = 4e-6
    for start, change in ((0.05, 2.86e-6), (0.1, -4.86e-6)):
        if t > start:
            value += change * (1.0 - np.exp(-(t - start) / TRANSDUCER_LAG_S))
    return float(value)


def accuracy(duration: float) -> tuple[float, float]:
    """(largest |h_hb / h_ref - 1| after 30 ms, largest |h_81x128 / h_ref - 1|) over the run."""
    rig, shape = RigParameters(), paper_shape()
    runs = [CoupledModel(rig, shape, nodes, steps).simulate(duration, excitation, 60e-6)
            for nodes, steps in ((41, 64), (81, 128))]
    reference = runs[1].height + (runs[1].height - runs[0].height) / 3
    plant = AveragedFilmPlant(rig, FilmForceTable(shape, 41, 6, rig=rig))
    averaged = plant.simulate(duration, excitation, 60e-6, samples=int(duration * 20000) + 1)
    error = np.abs(np.interp(runs[1].time, averaged.time, averaged.height) / reference - 1)
    return float(np.max(error[runs[1].time > 0.03])), float(np.max(np.abs(runs[1].height / reference - 1)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1 s of loop, 0.15 s of accuracy run")
    args = parser.parse_args()
    stop, duration = (1.0, 0.15) if args.quick else (3.7, 0.15)
    print(f"machine: {describe()}; load average {os.getloadavg()[0]:.2f}\n")
    with tempfile.TemporaryDirectory() as folder:
        archive = build_all(Path(folder) / "build", structures=("fig7_reynolds",))["fig7_reynolds"]
        rows = {}
        for solver in SOLVERS:
            loop_wall_time(archive, solver, 0.01, Path(folder) / "warm")  # imports, numba caches
            rows[solver] = loop_wall_time(archive, solver, stop, Path(folder) / solver)
    print(f"## fig7_reynolds, {stop:g} s simulated, whole run (set-up included)\n")
    print("| film solver | wall [s] | wall / simulated | set-up [s] | Plant doStep mean [us] |")
    print("|---|---|---|---|---|")
    for solver, (wall, summary) in rows.items():
        print(f"| {solver} | {wall:.2f} | {wall / stop:.2f} | {summary['initialization_wall_time_s']:.2f} | "
              f"{summary['timing']['Plant']['do_step_mean_us']:.0f} |")
    ratio = rows["time_marching"][0] / rows["harmonic_balance"][0]
    print(f"\nharmonic balance is {ratio:.1f}x faster than time marching (same run)\n")
    worst, reference_spread = accuracy(duration)
    print(f"## plant accuracy, open-loop |a| staircase, {duration:g} s\n")
    print(f"harmonic-balance plant vs Richardson(41x64, 81x128) time marching: largest height error after 30 ms "
          f"{worst:.2e} (target 5e-4); 81x128 vs the extrapolation: {reference_spread:.2e}")


if __name__ == "__main__":
    main()
