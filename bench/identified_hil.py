"""The identified design against the emulator, from rest, back to back with the paper's law (issue 14; docs/hil.md).

    python bench/identified_hil.py                          # the default truth and a heavier load
    python bench/identified_hil.py default damping-160-4 damping-115-8 calibration  # truths of bench/identify_truths.py
    python bench/identified_hil.py --noise --repeats 3      # sensor noise on: how quiet each law holds the levels

For each truth: ``nfal identify`` against ``nfal rig-emulator`` with that truth (bench/identify_truths.py), then
two ``nfal run fig7_hil`` runs, each against a fresh emulator (the object at rest on the surface, sensor noise off,
a 0.2 s watchdog): the paper's law as issue 14 found it (``PAPERS_LAW``: continuous placement on eq. (6), none of
the law's additions) and today's Controller on the identification. Where the paper's law has no design for the
truth's load, it is designed for the nominal one, as a user who did not re-weigh the object would run it.
Printed per run: overshoot and 2 % settling per step, the highest height during the first level (the lift-off),
the IAE of the steps (ratio to the paper's law) and of the first level (``metrics.first_level`` of summary.json);
then the identified loop simulated (fig7_slow with the truth as its plant, from rest). With ``--noise`` the
emulator's sensor noise is on (its default 2 um peak), each pair of runs is repeated and the noise RMS of every
level (measured h - r over the last quarter of its step, ``noise_rms_m``) is printed, pooled over the repeats.
Runs ride through host pauses up to 0.1 s (``proxy.max_missed_samples=200``, docs/hil.md).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import record
from identify_truths import cases, emulator_arguments, identify, truth_parameters

from nfal.apps.fig7_names import PAPERS_LAW
from nfal.models.rig import RigParameters
from nfal.models.table2 import STAIRCASE_LEVELS_M

PAPERS_LAW_ARGS = [f"{name}={value}" for name, value in PAPERS_LAW.items()]  # as --param values
#: The rig's nominal load [kg] (Table 2): the paper's law is designed for it where no design exists for a truth's.
NOMINAL_MASS = RigParameters.mass
#: The truths run by default: the emulator's default and a heavier load (0.18 kg) nobody designed for.
TRUTHS = ("default", "mass")


def hil_run(case: dict, folder: Path, name: str, controller: list[str], noise: bool = False) -> dict | str:
    """One fig7_hil run against a fresh emulator of the case's truth (sensor noise off unless ``noise``): its
    summary.json, or why it failed (a design that cannot be made for that rig, a lost link)."""
    link = folder / f"{name}.pty"
    quiet = [] if noise else ["--param", "SensorChain.noise_peak=0"]
    emulator = subprocess.Popen([sys.executable, "-m", "nfal", "rig-emulator", "--link", str(link), "--watchdog", "0.2",
                                 *quiet, *emulator_arguments(case)], stdout=subprocess.PIPE, text=True)
    try:
        emulator.stdout.readline()  # the port: the emulator is up
        parameters = [f"proxy.port={link}", "proxy.max_missed_samples=200", f"Controller.mass={case['mass']}",
                      *controller]
        done = subprocess.run([sys.executable, "-m", "nfal", "run", "fig7_hil", "--out", str(folder / name), "--json",
                               *(item for p in parameters for item in ("--param", p))],
                              capture_output=True, text=True, check=False)
        if done.returncode != 0:
            return f"nfal run exited {done.returncode}: {done.stderr.strip().splitlines()[-1]}"
        return json.loads(done.stdout)
    finally:
        emulator.terminate()
        emulator.wait(timeout=10)


#: fig7_hil's staircase as nfal run gives it (a 1 s first level for the lift-off), for the simulation.
HIL_STAIRCASE = "staircase:" + ",".join(f"{level:g}" for level in STAIRCASE_LEVELS_M) + ":0.6:1.0"
#: The emulator's truth beyond the case's parameters (ssp/rig_truth.ssv): the object at rest on the surface.
AT_REST = ["Plant.initial_height=5e-6", "Plant.rest_gap=5e-6", "Plant.near_surface=fast"]


def simulated_run(case: dict, folder: Path, name: str, controller: list[str], noise: bool = False) -> dict | str:
    """The same loop simulated: fig7_slow with the case's truth as its plant, from rest, the HIL staircase."""
    parameters = [*truth_parameters(case), *AT_REST, *([] if noise else ["SensorChain.noise_peak=0"]),
                  f"Controller.mass={case['mass']}", *controller]
    done = subprocess.run([sys.executable, "-m", "nfal", "run", "fig7_slow", "--out", str(folder / name), "--json",
                           "--reference", HIL_STAIRCASE, *(item for p in parameters for item in ("--param", p))],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        return f"nfal run exited {done.returncode}: {done.stderr.strip().splitlines()[-1]}"
    return json.loads(done.stdout)


def row(label: str, summary: dict | str, baseline: float | None) -> str:
    if isinstance(summary, str):
        return f"| {label} | {summary} | | | | | | |"
    metrics, first = summary["metrics"], summary["metrics"]["first_level"]
    steps = first["steps_iae_m_s"]
    ratio = "" if baseline is None else f" ({steps / baseline:.2f})"
    return (f"| {label} | " + ", ".join(f"{s['overshoot_percent']:.1f}" for s in metrics["steps"]) + " | "
            + ", ".join(f"{(s['settling_time_s'] or float('nan')) * 1e3:.0f}" for s in metrics["steps"])
            + f" | {first['peak_m'] * 1e6:.1f} | {steps * 1e6:.2f}{ratio} | {first['iae_m_s'] * 1e6:.2f} |"
            + f" {(summary.get('realtime') or {}).get('overruns', '')} | "
            + ", ".join(f"{s['noise_rms_m'] * 1e9:.0f}" for s in metrics["steps"])
            + " |")


def pooled_noise(label: str, summaries: list) -> str:
    """The noise RMS per level over the runs that finished, pooled (the root of the mean square)."""
    runs = [[s["noise_rms_m"] for s in summary["metrics"]["steps"]]
            for summary in summaries if isinstance(summary, dict)]
    if not runs:
        return f"| {label}, pooled | no run finished | | | | | | |"
    pooled = np.sqrt(np.mean(np.square(runs), axis=0))
    return (f"| {label}, pooled over {len(runs)} | | | | | | | " + ", ".join(f"{value * 1e9:.0f}" for value in pooled)
            + f" (all levels {np.sqrt(np.mean(np.square(runs))) * 1e9:.0f}) |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("truths", nargs="*", default=list(TRUTHS),
                        help=f"cases of bench/identify_truths.py (default: {' '.join(TRUTHS)})")
    parser.add_argument("--noise", action="store_true", help="the emulator's sensor noise on (default off)")
    parser.add_argument("--repeats", type=int, default=1, help="runs of each law per truth (default 1)")
    args = parser.parse_args()
    folder = Path("runs") / time.strftime("identified-hil-%Y%m%d-%H%M%S")
    folder.mkdir(parents=True)
    print(f"calibration files and runs in {folder}", flush=True)
    table = cases(folder)
    rows: list[str] = []

    def out(line: str) -> None:  # printed as it comes, and kept: the result file gets every row so far
        print(line, flush=True)
        rows.append(line)
        record.save("identified-hil" + ("-noise" if args.noise else ""), {"noise": args.noise, "rows": rows})

    for name in args.truths:
        case = table[name]
        calibration = folder / f"{name}.json"
        identify(case, folder, name)
        papers, identifieds = [], []
        for repeat in range(args.repeats):  # back to back, so a slow phase of the machine hits both laws
            paper, label = hil_run(case, folder, f"{name}-paper-{repeat}", PAPERS_LAW_ARGS, args.noise), "paper's law"
            if isinstance(paper, str) and case["mass"] != NOMINAL_MASS:  # no such design for this load: the nominal one
                paper = hil_run(case, folder, f"{name}-paper-nominal-{repeat}",
                                [*PAPERS_LAW_ARGS, f"Controller.mass={NOMINAL_MASS}"], args.noise)
                label = f"paper's law designed for {NOMINAL_MASS} kg"
            identified = hil_run(case, folder, f"{name}-identified-{repeat}", [f"Controller.calibration={calibration}"],
                                 args.noise)
            baseline = None if isinstance(paper, str) else paper["metrics"]["first_level"]["steps_iae_m_s"]
            out(row(f"{name}, {label}", paper, None))
            out(row(f"{name}, identified", identified, baseline))
            if repeat == 0:
                simulated = simulated_run(case, folder, f"{name}-identified-simulated",
                                          [f"Controller.calibration={calibration}"], args.noise)
                out(row(f"{name}, identified, simulated", simulated, baseline))
            papers.append(paper)
            identifieds.append(identified)
        if args.noise:
            out(pooled_noise(f"{name}, {label}", papers))
            out(pooled_noise(f"{name}, identified", identifieds))


def title(result: dict) -> str:
    return "The identified design against the emulator, beside the paper's law" + (
        " (sensor noise on)" if result["noise"] else "")


def tables(result: dict) -> list[record.Table]:
    return [record.Table("", ["truth, Controller", "overshoot % per step", "2 % settling [ms]", "lift-off peak [µm]",
                              "IAE steps [µm s] (ratio)", "IAE first level [µm s]", "host overruns",
                              "noise RMS per step [nm]"], [record.cells(line) for line in result["rows"]])]


if __name__ == "__main__":
    main()
