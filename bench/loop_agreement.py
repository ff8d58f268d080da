"""The agreement numbers quoted in docs/cosimulation.md and the README, over the full Fig. 9-10 staircase.

    python bench/loop_agreement.py      (from the repository root)

Prints: the FMU loop (transducer quasi-static, no analog filter) against the pure-Python loop of
``nfal compare`` (same seed); the default loop's deviation from 60 um during the 0.1 s lead under
``causal`` and ``jacobi``; and the largest height difference between the two algorithms.
"""

from __future__ import annotations

import tempfile

import numpy as np

from nfal.apps.build import build_all
from nfal.apps.fig7 import PURE_LOOP_PARAMETERS, SIMULATED, pure_python_loop
from nfal.models.closed_loop import Staircase
from nfal.orchestration import run_structure

HEIGHT = SIMULATED.height


def run(archive, folder, reference, **kwargs):
    return run_structure(archive, stop_time=reference.duration_s, step_size=5e-4, out_dir=folder, plot=False,
                         progress=False, inputs={"Controller.reference": reference}, **kwargs)


def main() -> None:
    reference = Staircase()
    with tempfile.TemporaryDirectory() as tmp:
        archive = build_all(f"{tmp}/build", structures=("fig7_slow",))["fig7_slow"]
        transparent = run(archive, f"{tmp}/pure", reference, parameters=PURE_LOOP_PARAMETERS)
        pure = pure_python_loop(reference)
        gap = np.max(np.abs(transparent[HEIGHT][: pure.height_m.size] - pure.height_m))
        print(f"FMU loop vs pure-Python loop (seed 0, 3.7 s): max |height difference| {gap:.2e} m")
        runs = {name: run(archive, f"{tmp}/{name}", reference, algorithm=name) for name in ("causal", "jacobi")}
        for name, result in runs.items():
            lead = result.table().time < reference.lead_s
            print(f"{name}: max |height - 60 um| in the lead "
                  f"{np.max(np.abs(result[HEIGHT][lead] - 60e-6)) * 1e6:.2f} um")
        difference = np.max(np.abs(runs["causal"][HEIGHT] - runs["jacobi"][HEIGHT]))
        print(f"causal vs jacobi: max |height difference| {difference * 1e6:.2f} um")


if __name__ == "__main__":
    main()
