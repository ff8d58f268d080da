"""The agreement numbers quoted in docs/cosimulation.md and the README, over the full Fig. 9-10 staircase.

    python bench/loop_agreement.py      (from the repository root)

Prints: the FMU loop (transducer quasi-static, no analog filter) against the pure-Python loop of
``nfal compare`` (same seed); the default loop's deviation from 60 um during the 0.1 s lead under
``causal`` and ``jacobi``; and the largest height difference between the two algorithms.
"""

from __future__ import annotations

import tempfile

import numpy as np

import record

from nfal.apps.build import build_all
from nfal.apps.fig7 import PURE_LOOP_PARAMETERS, SIMULATED, pure_python_loop
from nfal.models.reference import Staircase
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
        runs = {name: run(archive, f"{tmp}/{name}", reference, algorithm=name) for name in ("causal", "jacobi")}
        lead = {name: float(np.max(np.abs(result[HEIGHT][result.table().time < reference.lead_s] - 60e-6)))
                for name, result in runs.items()}
        difference = np.max(np.abs(runs["causal"][HEIGHT] - runs["jacobi"][HEIGHT]))
    result = {"staircase_s": reference.duration_s, "fmu_vs_pure_python_m": float(gap), "lead_deviation_m": lead,
              "causal_vs_jacobi_m": float(difference)}
    print(record.save("loop-agreement", result))
    record.show(tables(result))


def title(result: dict) -> str:
    return "The FMU loop against the pure-Python loop, and the two exchange algorithms"


def tables(result: dict) -> list[record.Table]:
    lead = result["lead_deviation_m"]
    return [record.Table(f"Over the full Fig. 9-10 staircase ({result['staircase_s']:g} s, seed 0):",
                         ["compared", "largest height difference"],
                         [["the FMU loop (transducer quasi-static, no analog filter) against the pure-Python loop of "
                           "`nfal compare`", f"{result['fmu_vs_pure_python_m']:.2e} m"],
                          ["the default loop's deviation from 60 µm during the lead, `causal`",
                           f"{lead['causal'] * 1e6:.2f} µm"],
                          ["the same, `jacobi`", f"{lead['jacobi'] * 1e6:.2f} µm"],
                          ["`causal` against `jacobi`", f"{result['causal_vs_jacobi_m'] * 1e6:.2f} µm"]])]

if __name__ == "__main__":
    main()
