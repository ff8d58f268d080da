"""What a fresh process pays before its work starts: the Controller FMU's set-up and the rig emulator's start.

    python bench/bench_startup.py [--runs 5]

Each measurement is a new Python, as a host's embedded interpreter or `nfal rig-emulator` is:

* the Controller slave class's import, set-up and first step, its schedule in the nfal cache (one run before fills
  it), wall time in that process; the baseline, in the same run, does the same after importing scipy.interpolate,
  which the set-up needed before the gain spline's coefficients were cached (with it, scipy.optimize, .special and
  .sparse);
* `nfal rig-emulator` on rig_slow from its start to the line that gives its port: wall time, and its CPU time then
  (``/proc/<pid>/stat``); what the suite's warm emulators (tests/helpers/warm_nfal.py) no longer pay each.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import record

from nfal.apps.build import build_all

#: The Controller's set-up in a fresh process, timed there; ``{before}`` is what runs first.
CONTROLLER = """import time
started = time.perf_counter()
{before}
from nfal.fmus.controller import Controller
slave = Controller(instance_name="c")
slave.setup_experiment(0.0); slave.enter_initialization_mode(); slave.exit_initialization_mode()
slave.do_step(0.0, 5e-4)
print(time.perf_counter() - started)
"""
VARIANTS = {"cached schedule": "", "baseline: scipy.interpolate imported first": "import scipy.interpolate"}


def controller_setup(before: str) -> float:
    done = subprocess.run([sys.executable, "-c", CONTROLLER.format(before=before)], capture_output=True, text=True,
                          check=True)
    return float(done.stdout.split()[-1])


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def emulator_start(truth: Path, link: Path) -> tuple[float, float]:
    """Wall and CPU time [s] from `nfal rig-emulator`'s start to its port line."""
    started = time.perf_counter()
    process = subprocess.Popen([sys.executable, "-m", "nfal", "rig-emulator", "--truth", str(truth), "--link",
                                str(link), "--duration", "30"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
    try:
        if not process.stdout.readline().strip():
            raise RuntimeError(f"the emulator did not start: {process.communicate(timeout=30)[1]}")
        return time.perf_counter() - started, cpu_seconds(process.pid)
    finally:
        process.terminate()
        process.communicate(timeout=30)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    controller_setup("")  # the schedule (designs and gain spline) into the cache
    data = {"runs": args.runs, "controller_s": {name: [] for name in VARIANTS}, "emulator_wall_s": [],
            "emulator_cpu_s": []}
    with tempfile.TemporaryDirectory() as folder:
        truth = build_all(Path(folder), structures=("rig_slow",))["rig_slow"]
        for run in range(args.runs):
            for name, before in VARIANTS.items():  # interleaved: the machine's drift falls on both alike
                data["controller_s"][name].append(round(controller_setup(before), 4))
            wall, cpu = emulator_start(truth, Path(folder) / f"rig{run}")
            data["emulator_wall_s"].append(round(wall, 3))
            data["emulator_cpu_s"].append(round(cpu, 2))
            print(run, {name: values[-1] for name, values in data["controller_s"].items()}, wall, cpu, flush=True)
    print(record.save("startup", data))
    record.show(tables(data), findings(data))


def _span(values: list[float], digits: int = 2) -> str:
    return f"{min(values):.{digits}f}-{max(values):.{digits}f} (median {np.median(values):.{digits}f})"


def tables(result: dict) -> list[record.Table]:
    return [record.Table(f"{result['runs']} fresh processes each, interleaved:", ["what", "seconds"],
                         [*([f"Controller import, set-up and first step: {name}", _span(values)]
                            for name, values in result["controller_s"].items()),
                          ["`nfal rig-emulator` to its port line: wall", _span(result["emulator_wall_s"])],
                          ["`nfal rig-emulator` to its port line: its CPU", _span(result["emulator_cpu_s"])]])]


def findings(result: dict) -> list[str]:
    ours, baseline = (np.median(values) for values in result["controller_s"].values())
    return [f"The Controller with its schedule cached sets up in {ours / baseline:.2f}x the time it takes when "
            "scipy.interpolate is imported too (the baseline, same run: what the set-up paid before the gain "
            "spline's coefficients were cached).",
            f"Each `nfal rig-emulator` had used {np.median(result['emulator_cpu_s']):.2f} s of CPU (median) when it "
            "gave its port: the interpreter's start, nfal's and numba's imports and the plant's kernels."]


if __name__ == "__main__":
    main()
