"""The Reynolds loop against the slow loop, step by step (issue 29): overshoot per step and IAE. Prints markdown and
writes bench/results/reynolds-tracking.json.

    python bench/reynolds_tracking.py [--noise-off]

Rows: fig7_slow with its defaults and running the Reynolds loop's law (``nfal.apps.fig7.reynolds_law()``), and
fig7_reynolds with its defaults and with the paper's law (``PAPERS_LAW``: continuous placement, none of the law's
additions), on the stand-in form (its 60/100 um steps), a piston (Figs. 9-10's whole staircase) and the vibrometer
scan of examples/shapes. The issue's criterion: fig7_reynolds' worst overshoot at most fig7_slow's + 2 points on the
same steps, for the stand-in form and the piston.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import record

from nfal.apps.build import build_all
from nfal.apps.fig7 import DEFAULT_STAIRCASES, loop_metrics, matched_design, reynolds_law
from nfal.apps.fig7_names import PAPERS_LAW
from nfal.models.reference import Staircase
from nfal.orchestration import run_structure

FILM_STEPS = DEFAULT_STAIRCASES["fig7_reynolds"]
STAIRCASE = Staircase()
SCAN = str(Path(__file__).resolve().parents[1] / "examples" / "shapes" / "vibrometer_scan.csv")
PISTON = {"Plant.shape": "piston", "Controller.reference_max": 200e-6}
#: (name, structure, reference, parameters)
CASES = (
    ("fig7_slow, defaults, 60/100 um steps", "fig7_slow", FILM_STEPS, {}),
    ("fig7_slow, the Reynolds loop's law, 60/100 um steps", "fig7_slow", FILM_STEPS, reynolds_law()),
    ("fig7_slow, defaults, staircase", "fig7_slow", STAIRCASE, {}),
    ("fig7_slow, the Reynolds loop's law, staircase", "fig7_slow", STAIRCASE, reynolds_law()),
    ("fig7_reynolds, stand-in form (defaults)", "fig7_reynolds", FILM_STEPS, {}),
    ("fig7_reynolds, stand-in form, paper's law", "fig7_reynolds", FILM_STEPS, PAPERS_LAW),
    ("fig7_reynolds, piston, staircase", "fig7_reynolds", STAIRCASE, PISTON),
    ("fig7_reynolds, piston, staircase, paper's law", "fig7_reynolds", STAIRCASE, {**PISTON, **PAPERS_LAW}),
    ("fig7_reynolds, vibrometer scan, 60/100 um steps", "fig7_reynolds", FILM_STEPS, {"Plant.shape": SCAN}),
)


def measure(archives: dict, structure: str, reference: Staircase, parameters: dict, noise: bool, out: Path) -> dict:
    quiet = {} if noise else {"SensorChain.noise_peak": 0.0}
    started = time.perf_counter()
    result = run_structure(archives[structure], stop_time=reference.duration_s, step_size=5e-4,
                           inputs={"Controller.reference": reference}, out_dir=out, plot=False, progress=False,
                           parameters=matched_design({**parameters, **quiet}))
    metrics = loop_metrics(result.table(), reference)
    overshoot = [step["overshoot_percent"] for step in metrics["steps"]]
    return {"overshoot_percent": overshoot, "worst_percent": max(overshoot), "iae_m_s": metrics["iae"],
            "saturation": metrics["saturation"], "wall_s": time.perf_counter() - started}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--noise-off", action="store_true", help="the sensor's noise off (default: on, seed 0)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        archives = build_all(Path(folder) / "build", structures=("fig7_slow", "fig7_reynolds"))
        rows = {name: measure(archives, structure, reference, parameters, not args.noise_off,
                              Path(folder) / f"run{i}")
                for i, (name, structure, reference, parameters) in enumerate(CASES)}
    slow = {"stand-in": rows[CASES[1][0]]["worst_percent"], "piston": rows[CASES[3][0]]["worst_percent"]}
    criterion = {"stand-in form": rows[CASES[4][0]]["worst_percent"] <= slow["stand-in"] + 2.0,
                 "piston": rows[CASES[6][0]]["worst_percent"] <= slow["piston"] + 2.0}
    result = {"bench": "reynolds-tracking" + ("-noise-off" if args.noise_off else ""), "rows": rows,
              "criterion_met": criterion}
    print(record.save(result["bench"], result))
    record.show(tables(result), findings(result))


def title(result: dict) -> str:
    return "The Reynolds loop against the slow loop, step by step" + (
        " (the sensor's noise off)" if result["bench"].endswith("noise-off") else "")


def tables(result: dict) -> list[record.Table]:
    return [record.Table("", ["loop", "overshoot per step [%]", "worst [%]", "IAE [µm·s]"],
                         [[name, ", ".join(f"{value:.2f}" for value in row["overshoot_percent"]),
                           f"{row['worst_percent']:.2f}", f"{row['iae_m_s'] * 1e6:.3f}"]
                          for name, row in result["rows"].items()])]


def findings(result: dict) -> list[str]:
    return ["Worst overshoot of fig7_reynolds at most fig7_slow's (the same law) + 2 points: "
            + ", ".join(f"{case}: {'met' if met else 'not met'}" for case, met in result["criterion_met"].items())
            + "."]

if __name__ == "__main__":
    main()
