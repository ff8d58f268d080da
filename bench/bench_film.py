"""Film-solver benchmarks: time-marching K(sigma) and the full coupled model. Prints a markdown table.

    NUMBA_NUM_THREADS=1 python bench/bench_film.py [--quick]

Goals (issue): K at 50 squeeze numbers on [5, 500] (101 nodes, 256 steps per period, delta = 0.01) in
<= 5 s; 1 s of rig time of the paper's rig (134.7 g, 28.5 kHz, paper shape, |a| for ~100 um) with the
slow height within 0.05 % of a converged reference in <= 5 s (stretch: <= 1 s).
"""

from __future__ import annotations

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import record  # noqa: E402

from nfal.models.calibration import perturbation_calibration  # noqa: E402
from nfal.models.coupled import CoupledModel  # noqa: E402
from nfal.models.excitation import paper_shape  # noqa: E402
from nfal.models.perturbation import perturbation_K  # noqa: E402
from nfal.models.plant import SimplifiedPlant  # noqa: E402
from nfal.models.reynolds import time_marching_K  # noqa: E402
from nfal.models.rig import RigParameters  # noqa: E402


def timed(function, *args, **kwargs):
    start = time.perf_counter()
    result = function(*args, **kwargs)
    return result, time.perf_counter() - start


def bench_K(shape) -> list[tuple]:
    sigma = np.geomspace(5.0, 500.0, 50)
    _, compile_time = timed(time_marching_K, shape, [5.0, 50.0], nodes=11, steps_per_period=16)  # numba JIT/cache load
    K_tm, tm_time = timed(time_marching_K, shape, sigma, delta=0.01, nodes=101, steps_per_period=256)
    K_pert, pert_time = timed(perturbation_K, shape, sigma, 101)
    _, default_time = timed(perturbation_K, shape, sigma)  # the default 401 nodes: the goal <= 0.1 s
    gap = np.max(np.abs(K_tm - K_pert))
    return [
        ("K(sigma), 50 points on [5, 500], perturbation route (baseline), 101 nodes", pert_time, 1.0, "-"),
        ("K(sigma), 50 points, perturbation route, default 401 nodes (goal <= 0.1 s)", default_time,
         default_time / pert_time, "-"),
        ("K(sigma), 50 points, time marching, 101 nodes, 256 steps/period, delta = 0.01", tm_time, tm_time / pert_time,
         f"max abs K gap to perturbation {gap:.1e}"),
        ("numba compile / cache load of the film kernels (first call)", compile_time, float("nan"), "-"),
    ]


def bench_coupled(shape, quick: bool) -> list[tuple]:
    rig = RigParameters()
    plant = SimplifiedPlant(rig, perturbation_calibration(shape))
    excitation = float(plant.equilibrium_excitation(100e-6))
    duration = 0.2 if quick else 1.0
    release = 120e-6
    CoupledModel(rig, shape, nodes=11, steps_per_period=16).simulate(0.0005, excitation, 100e-6)  # compile

    def run(nodes, steps, envelope):
        model = CoupledModel(rig, shape, nodes=nodes, steps_per_period=steps, envelope=envelope)
        return timed(model.simulate, duration, excitation, release)

    # Converged reference: Richardson (second order in dR and dT together) of 81 x 128 and 161 x 256.
    medium, medium_time = run(81, 128, True)
    fine, fine_time = run(161, 256, True)
    reference = fine.height + (fine.height - medium.height) / 3.0
    rows = []
    for nodes, steps, envelope in ((41, 64, False), (41, 64, True), (81, 128, False), (81, 128, True),
                                   (101, 256, True)):
        if (nodes, steps, envelope) == (81, 128, True):
            result, elapsed = medium, medium_time
        else:
            result, elapsed = run(nodes, steps, envelope)
        deviation = np.abs(result.height - reference) / reference
        rows.append((f"coupled, {duration:g} s rig time, {nodes} nodes x {steps} steps, "
                     f"{'envelope following' if envelope else 'every period'} "
                     f"({result.marched_periods}/{result.height.size} periods marched)",
                     elapsed, elapsed / duration,
                     f"slow height vs reference: max {100 * deviation.max():.3f} %, final {100 * deviation[-1]:.3f} %"))
    fine_dev = np.abs(fine.height - reference) / reference
    rows.append((f"coupled reference run, 161 x 256, envelope following ({fine.marched_periods} periods marched)",
                 fine_time, fine_time / duration,
                 f"its own Richardson correction: max {100 * fine_dev.max():.3f} %; |a| = {excitation * 1e6:.3f} um, "
                 f"released at {release * 1e6:g} um, final height {reference[-1] * 1e6:.4f} um"))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="0.2 s of rig time instead of 1 s")
    args = parser.parse_args()
    shape = paper_shape()
    rows = bench_K(shape) + bench_coupled(shape, args.quick)
    result = {"numba_threads": os.environ["NUMBA_NUM_THREADS"],
              "rows": [{"case": name, "wall_s": seconds, "ratio": None if np.isnan(ratio) else ratio, "notes": notes}
                       for name, seconds, ratio, notes in rows]}
    print(record.save("film", result))
    record.show(tables(result))


def title(result: dict) -> str:
    return "Film solvers: K(σ) and the coupled model"


def tables(result: dict) -> list[record.Table]:
    return [record.Table(f"NUMBA_NUM_THREADS = {result['numba_threads']}. Ratio: K rows, wall time / the perturbation "
                         "route's (the baseline, same run); coupled rows, wall time / rig time (1 = real time).",
                         ["case", "wall time [s]", "ratio", "notes"],
                         [[row["case"], f"{row['wall_s']:.3f}", "-" if row["ratio"] is None else f"{row['ratio']:.2f}",
                           row["notes"]] for row in result["rows"]])]

if __name__ == "__main__":
    main()
