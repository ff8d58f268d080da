"""HIL against simulation: the numbers docs/hil.md quotes. Prints a markdown table.

    python bench/hil_agreement.py                      (paced on the wall clock)
    python bench/hil_agreement.py --lockstep           (the rig ticks on the host's DRIVEs: docs/hil.md, "Lockstep")
    python bench/hil_agreement.py --lockstep --param Plant.mass=0.15
                                                       (another truth: the override goes to the emulator's plant and
                                                        to the simulated one)

Runs `nfal rig-emulator` (rig_slow truth, sensor noise off) in a child process and fig7_hil in real time
tracking 100 -> 140 um, then the simulated loop fig7_slow with the truth's parameters, and compares: the
comparison of tests/test_hil_end_to_end.py::test_hil_tracks_a_step_like_the_simulation_of_the_truth, paced on the
wall clock where the test runs in lockstep (one run as it comes, whether or not the machine stalled during it).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import record

from nfal.apps.build import build_all
from nfal.cli.commands.cosim import parse_parameter
from nfal.apps.fig7 import HARDWARE, SIMULATED, loop_metrics
from nfal.models.reference import Staircase
from nfal.orchestration import run_structure

TRUTH = {"Plant.initial_height": 5e-6, "Plant.excess_damping_height": 137e-6, "Plant.excess_damping_exponent": 6.0,
         "Plant.near_surface": "fast", "SensorChain.noise_peak": 0.0}
STEP = Staircase((100e-6, 140e-6), hold_s=1.0, lead_s=1.0)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lockstep", action="store_true", help="rig and host in lockstep, the master not paced")
    parser.add_argument("--param", action="append", default=[], metavar="Plant.VAR=VALUE",
                        help="override a parameter of the truth, on both sides (repeatable)")
    args = parser.parse_args()
    overrides = dict(parse_parameter(text) for text in args.param)  # ELEMENT.VAR=VALUE, checked as nfal run does
    with tempfile.TemporaryDirectory(prefix="nfal-hil-agreement-") as temp:
        archives = build_all(Path(temp) / "build", structures=("fig7_slow", "fig7_hil", "rig_slow"))
        emulator = subprocess.Popen([sys.executable, "-m", "nfal", "rig-emulator", "--truth", str(archives["rig_slow"]),
                                     "--param", "SensorChain.noise_peak=0", "--watchdog", "0.2",
                                     *(["--lockstep"] if args.lockstep else []),
                                     *(f"--param={text}" for text in args.param)],
                                    stdout=subprocess.PIPE, text=True)
        try:
            port = emulator.stdout.readline().strip()
            proxy = {"proxy.lockstep": True} if args.lockstep else {"proxy.max_missed_samples": 2000}
            hil = run_structure(archives["fig7_hil"], stop_time=STEP.duration_s, inputs={"Controller.reference": STEP},
                                parameters={"proxy.port": port, **proxy}, realtime=not args.lockstep,
                                plot=False, out_dir=Path(temp) / "hil")
        finally:
            emulator.terminate()
            emulator.communicate(timeout=30)
        simulated = run_structure(archives["fig7_slow"], stop_time=STEP.duration_s,
                                  inputs={"Controller.reference": STEP}, parameters={**TRUTH, **overrides}, plot=False,
                                  out_dir=Path(temp) / "sim")
        t = hil.table().time
        difference = np.abs(np.asarray(hil[HARDWARE.measured]) - np.asarray(simulated[SIMULATED.measured]))
        [ours] = loop_metrics(hil.table(), STEP, HARDWARE)["steps"]
        [theirs] = loop_metrics(simulated.table(), STEP, SIMULATED)["steps"]
    transient = np.max(difference[(t >= 1.0) & (t < 1.2)])
    holds = max(np.max(difference[(t >= a) & (t < b)]) for a, b in ((0.5, 1.0), (1.5, 2.0)))
    lift_offs = [lift_off(t, np.asarray(run[column])) for run, column in ((hil, HARDWARE.measured),
                                                                          (simulated, SIMULATED.measured))]
    rows = [["rise time 100 → 140 µm", f"{ours['rise_time_s'] * 1e3:.1f} ms", f"{theirs['rise_time_s'] * 1e3:.1f} ms"],
            ["overshoot", f"{ours['overshoot_percent']:.2f} %", f"{theirs['overshoot_percent']:.2f} %"],
            ["settling time", f"{ours['settling_time_s'] * 1e3:.1f} ms", f"{theirs['settling_time_s'] * 1e3:.1f} ms"],
            ["largest height difference in the step's first 0.2 s", f"{transient * 1e6:.2f} µm", ""],
            ["largest difference over the last half of each hold", f"{holds * 1e6:.3f} µm", ""],
            ["lift-off, first 0.2 s", f"{np.max(difference[t < 0.2]) * 1e6:.2f} µm", ""],
            ["largest difference over the whole run, from rest", f"{np.max(difference) * 1e6:.2f} µm", ""],
            ["lift-off from rest to 100 µm: peak", *(f"{peak * 1e6:.1f} µm at {at * 1e3:.0f} ms"
                                                     for peak, at, _ in lift_offs)],
            ["within 3 µm of 100 µm from", *(f"{within * 1e3:.0f} ms" for _, _, within in lift_offs)]]
    result = {"lockstep": args.lockstep, "overrides": overrides, "rows": rows}
    print(record.save("hil-agreement" + ("-lockstep" if args.lockstep else ""), result))
    record.show(tables(result))
    return 0


def lift_off(t: np.ndarray, height: np.ndarray, level: float = STEP.levels_m[0], band: float = 3e-6):
    """Over the first level's hold: the peak height [m], when it came [s], and from when on the height stays
    within ``band`` of the level [s]."""
    hold = t < STEP.lead_s
    outside = np.flatnonzero(np.abs(height[hold] - level) > band)
    peak = int(np.argmax(height[hold]))
    return height[peak], t[peak], t[outside[-1] + 1] if outside.size else 0.0


def title(result: dict) -> str:
    return ("HIL against simulation, " + ("in lockstep" if result["lockstep"] else "paced on the wall clock")
            + (f", truth overrides {result['overrides']}" if result["overrides"] else ""))


def tables(result: dict) -> list[record.Table]:
    return [record.Table("fig7_hil against the emulator (rig_slow truth, sensor noise off) and fig7_slow with the "
                         "truth's parameters, 100 -> 140 µm:", ["", "HIL", "simulated"], result["rows"])]


if __name__ == "__main__":
    sys.exit(main())
