"""The identified design against the emulator, from rest, back to back with the paper's law (issue 14; docs/hil.md).

    python bench/identified_hil.py                    # the default truth and a heavier load (bench/ folder)
    python bench/identified_hil.py default mass       # some truths of bench/identify_truths.py

For each truth: ``nfal identify`` against ``nfal rig-emulator`` with that truth (bench/identify_truths.py), then
two ``nfal run fig7_hil`` runs, each against a fresh emulator (the object at rest on the surface, sensor noise off,
a 0.2 s watchdog): the paper's law as issue 14 found it (continuous placement on eq. (6), no lead, no lift-off mode)
and today's Controller on the identification. Printed per run: overshoot and 2 % settling per step, the highest
height during the first level (the lift-off), the IAE of the steps (ratio to the paper's law) and of the first
level (``metrics.first_level`` of summary.json).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

from identify_truths import cases, emulator_arguments, identify

PAPER_LAW = ["Controller.placement=continuous", "Controller.actuator_lag=0", "Controller.lift_off_time=0"]
#: The truths run by default: the emulator's default and a heavier load (0.18 kg) nobody designed for.
TRUTHS = ("default", "mass")


def hil_run(case: dict, folder: Path, name: str, controller: list[str]) -> dict | str:
    """One fig7_hil run against a fresh emulator of the case's truth (noise off): its summary.json, or why it
    failed (a design that cannot be made for that rig, a lost link)."""
    link = folder / f"{name}.pty"
    emulator = subprocess.Popen([sys.executable, "-m", "nfal", "rig-emulator", "--link", str(link), "--watchdog", "0.2",
                                 "--param", "SensorChain.noise_peak=0", *emulator_arguments(case)],
                                stdout=subprocess.PIPE, text=True)
    try:
        emulator.stdout.readline()  # the port: the emulator is up
        parameters = [f"proxy.port={link}", f"Controller.mass={case['mass']}", *controller]
        done = subprocess.run([sys.executable, "-m", "nfal", "run", "fig7_hil", "--out", str(folder / name), "--json",
                               *(item for p in parameters for item in ("--param", p))], capture_output=True, text=True)
        if done.returncode != 0:
            return f"nfal run exited {done.returncode}: {done.stderr.strip().splitlines()[-1]}"
        return json.loads(done.stdout)
    finally:
        emulator.terminate()
        emulator.wait(timeout=10)


def row(label: str, summary: dict | str, baseline: float | None) -> str:
    if isinstance(summary, str):
        return f"| {label} | {summary} | | | | | |"
    metrics, first = summary["metrics"], summary["metrics"]["first_level"]
    steps = first["steps_iae_m_s"]
    ratio = "" if baseline is None else f" ({steps / baseline:.2f})"
    return (f"| {label} | " + ", ".join(f"{s['overshoot_percent']:.1f}" for s in metrics["steps"]) + " | "
            + ", ".join(f"{(s['settling_time_s'] or float('nan')) * 1e3:.0f}" for s in metrics["steps"])
            + f" | {first['peak_m'] * 1e6:.1f} | {steps * 1e6:.2f}{ratio} | {first['iae_m_s'] * 1e6:.2f} |"
            + f" {summary['realtime']['overruns']} |")


def main(names: list[str]) -> None:
    folder = Path("runs") / time.strftime("identified-hil-%Y%m%d-%H%M%S")
    folder.mkdir(parents=True)
    print(f"calibration files and runs in {folder}", flush=True)
    table = cases(folder)
    print("| truth, Controller | overshoot % per step | 2 % settling [ms] | lift-off peak [um] "
          "| IAE steps [um s] (ratio) | IAE first level [um s] | host overruns |")
    print("|---|---|---|---|---|---|---|")
    for name in names or TRUTHS:
        case = table[name]
        calibration = folder / f"{name}.json"
        identify(case, folder, name)
        paper = hil_run(case, folder, f"{name}-paper", PAPER_LAW)
        identified = hil_run(case, folder, f"{name}-identified", [f"Controller.calibration={calibration}"])
        baseline = None if isinstance(paper, str) else paper["metrics"]["first_level"]["steps_iae_m_s"]
        print(row(f"{name}, paper's law", paper, None), flush=True)
        print(row(f"{name}, identified", identified, baseline), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
