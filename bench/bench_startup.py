"""What a process pays before its work starts, and what it no longer pays again: set-ups, starts, extractions, builds.

    python bench/bench_startup.py [--runs 5]

Each measurement is a new Python, as a host's embedded interpreter or `nfal rig-emulator` is:

* the Controller slave class's import, set-up and first step, its schedule in the nfal cache (one run before fills
  it), wall time in that process; the baseline, in the same run, does the same after importing scipy.interpolate,
  which the set-up needed before the gain spline's coefficients were cached (with it, scipy.optimize, .special,
  .linalg and .sparse);
* `nfal rig-emulator` on rig_slow from its start to the line that gives its port: wall time, and its CPU time then
  (``/proc/<pid>/stat``); what the suite's warm emulators (tests/helpers/warm_nfal.py) no longer pay each;
* 10 short fig7_slow runs (0.01 s) in one Python, each FMU extracted once per content as the master does
  (orchestration/fmu_folders.py), against the baseline, in the same run, of every FMU extracted anew for each run
  (each folder forgotten after its run, as before fmu_folders): wall time of the runs, the process's peak memory;
* an FMU built (``build_fmu(..., force=True)``) against the same FMU built into another folder, a copy from the
  nfal cache (fmus/build.py), after one warm-up build;
* the SlowPlant slave's import, set-up and a 10 ms run (20 steps of 0.5 ms), CPU time, with the host's stop time of
  10 ms declared (its kernels as Python: fmus/slow_plant.py) against the baseline, in the same run, of no stop time
  declared (compiled at set-up); then the mean wall time of 200 more steps, each way;
* a 10 ms run of the SlowPlant and of the Controller FMU in the C host (fmus/hosts/fmi2_host.c, nothing else in its
  environment), CPU per run, the Python the FMU starts running one OpenBLAS thread (fmus/loader/loader.c) against the
  baseline, in the same run, of the host asking for one per core (``OPENBLAS_NUM_THREADS=<nproc>``: each pool's
  threads spin idle at its start, as they all did before the loader set one).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import record
from machine import cpu_seconds

from nfal.apps.build import build_all
from nfal.apps.host_check import bare_environment, compile_c_host, run_in_c_host
from nfal.fmus.build import build_fmu, build_fmus

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


#: Short fig7_slow runs in one Python; with "fresh", each FMU is extracted anew for every run.
REPEATED_RUNS = """import json, resource, sys, tempfile, time
from nfal.orchestration import fmu_folders, run_structure
archive, runs, fresh = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "fresh"
started = time.perf_counter()
with tempfile.TemporaryDirectory() as out:
    for k in range(runs):
        run_structure(archive, stop_time=0.01, plot=False, progress=False, out_dir=out, overwrite=True)
        if fresh:
            for folder in list(fmu_folders._folders.values()):
                fmu_folders.forget(folder)
print(json.dumps({"wall_s": time.perf_counter() - started,
                  "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""
MODES = {"extracted once per content": "once", "baseline: extracted anew for each run": "fresh"}
REPEATED = 10


def repeated_runs(archive: Path, runs: int, mode: str) -> dict:
    done = subprocess.run([sys.executable, "-c", REPEATED_RUNS, str(archive), str(runs), mode], capture_output=True,
                          text=True, check=True)
    return {key: round(value, 2) for key, value in json.loads(done.stdout.splitlines()[-1]).items()}


#: The SlowPlant slave in a new Python: import, set-up with ``stop`` declared, 20 steps (CPU time), 200 more (a step).
SLOW_PLANT = """import resource, time
from nfal.fmus.slow_plant import SlowPlant
slave = SlowPlant(instance_name="p")
slave.setup_experiment(0.0, {stop}); slave.exit_initialization_mode(); slave.excitation_amplitude = 3e-6
for k in range(20):
    slave.do_step(k * 5e-4, 5e-4)
usage = resource.getrusage(resource.RUSAGE_SELF)
started = time.perf_counter()
for k in range(20, 220):
    slave.do_step(k * 5e-4, 5e-4)
print(usage.ru_utime + usage.ru_stime, (time.perf_counter() - started) / 200)
"""
STOPS = {"10 ms declared: kernels as Python": 0.01, "baseline: no stop declared: compiled at set-up": None}
#: The C host's environment: nothing set up, or (the baseline) a BLAS thread per core asked for.
BLAS = {"nothing set up: one BLAS thread": {},
        "baseline: OPENBLAS_NUM_THREADS=nproc": {"OPENBLAS_NUM_THREADS": str(os.cpu_count())}}
C_HOST_FMUS = ("SlowPlant", "Controller")


def slow_plant_run(stop: float | None) -> tuple[float, float]:
    """(CPU [s] of a 10 ms run from the process's start, one step's wall time [s] after it)."""
    done = subprocess.run([sys.executable, "-c", SLOW_PLANT.format(stop=stop)], capture_output=True, text=True,
                          check=True)
    cpu, step = done.stdout.split()[-2:]
    return float(cpu), float(step)


def c_host_cpu(host: Path, fmu: Path, folder: Path, extra: dict[str, str]) -> float:
    """CPU [s] of one 10 ms run of ``fmu`` in the C host, in an environment of ``extra`` alone."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    runs = run_in_c_host(host, fmu, folder, runs=1, env=bare_environment(**extra))
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if runs.exit_codes != [0]:
        raise RuntimeError(f"the C host failed on {fmu.name}: {runs.first_failure[-2000:]}")
    return after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime


def build_seconds(folder: Path, force: bool) -> float:
    started = time.perf_counter()
    build_fmu("SlowPlant", folder, force=force)
    return time.perf_counter() - started



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
        archive = build_all(Path(folder), structures=("fig7_slow",))["fig7_slow"]
        data["repeated_runs"] = {name: repeated_runs(archive, REPEATED, mode) for name, mode in MODES.items()}
        build_seconds(Path(folder) / "warm-up", True)  # pythonfmu and the slave modules imported
        data["build_s"] = {"copied from the nfal cache": [], "baseline: built (force=True)": []}
        for run in range(args.runs):  # interleaved
            for name, force in zip(data["build_s"], (False, True)):
                data["build_s"][name].append(round(build_seconds(Path(folder) / f"{run}-{force}", force), 4))
        print(data["repeated_runs"], data["build_s"], flush=True)
    data["slow_plant"] = {mode: {"cpu_s": [], "step_s": []} for mode in STOPS}
    data["c_host_cpu_s"] = {name: {mode: [] for mode in BLAS} for name in C_HOST_FMUS}
    with tempfile.TemporaryDirectory() as folder:
        fmus = build_fmus(Path(folder) / "fmus", C_HOST_FMUS)
        host = compile_c_host(Path(folder) / "host")
        for run in range(args.runs):  # interleaved
            for mode, stop in STOPS.items():
                cpu, step = slow_plant_run(stop)
                data["slow_plant"][mode]["cpu_s"].append(round(cpu, 3))
                data["slow_plant"][mode]["step_s"].append(round(step, 7))
            for name, modes in data["c_host_cpu_s"].items():
                for mode, extra in BLAS.items():
                    modes[mode].append(round(c_host_cpu(host, fmus[name], Path(folder) / f"{name}-{mode[:8]}-{run}",
                                                        extra), 3))
    print(data["slow_plant"], data["c_host_cpu_s"], flush=True)
    print(record.save("startup", data))
    record.show(tables(data), findings(data))


def _span(values: list[float], digits: int = 2) -> str:
    return f"{min(values):.{digits}f}-{max(values):.{digits}f} (median {np.median(values):.{digits}f})"


def tables(result: dict) -> list[record.Table]:
    return [record.Table(f"{result['runs']} fresh processes each, interleaved:", ["what", "seconds"],
                         [*([f"Controller import, set-up and first step: {name}", _span(values)]
                            for name, values in result["controller_s"].items()),
                          ["`nfal rig-emulator` to its port line: wall", _span(result["emulator_wall_s"])],
                          ["`nfal rig-emulator` to its port line: its CPU", _span(result["emulator_cpu_s"])],
                          *([f"SlowPlant.fmu {name}", _span(values, 3)]
                            for name, values in result["build_s"].items())]),
            record.Table(f"{REPEATED} fig7_slow runs of 0.01 s in one Python:",
                         ["FMUs", "wall [s]", "peak memory [MiB]"],
                         [[name, f"{row['wall_s']:.2f}", f"{row['peak_mib']:.0f}"]
                          for name, row in result["repeated_runs"].items()]),
            record.Table(f"The SlowPlant slave in a new Python, {result['runs']} runs each, interleaved:",
                         ["host's stop time", "CPU of import, set-up and 20 steps [s]", "a step after [µs]"],
                         [[mode, _span(row["cpu_s"]), _span([1e6 * s for s in row["step_s"]], 0)]
                          for mode, row in result["slow_plant"].items()]),
            record.Table(f"A 10 ms run in the C host, {result['runs']} runs each, interleaved:",
                         ["FMU", "host's environment", "CPU [s]"],
                         [[name, mode, _span(values)] for name, modes in result["c_host_cpu_s"].items()
                          for mode, values in modes.items()])]


def findings(result: dict) -> list[str]:
    ours, baseline = (np.median(values) for values in result["controller_s"].values())
    once, fresh = result["repeated_runs"].values()
    copied, built = (np.median(values) for values in result["build_s"].values())
    return [f"The Controller with its schedule cached sets up in {ours / baseline:.2f}x the time it takes when "
            "scipy.interpolate is imported too (the baseline, same run: what the set-up paid before the gain "
            "spline's coefficients were cached).",
            f"Each `nfal rig-emulator` had used {np.median(result['emulator_cpu_s']):.2f} s of CPU (median) when it "
            "gave its port: the interpreter's start, nfal's and numba's imports and the plant's kernels.",
            f"{REPEATED} short runs in one Python take {once['wall_s'] / fresh['wall_s']:.2f}x the wall time and "
            f"{once['peak_mib'] / fresh['peak_mib']:.2f}x the peak memory with each FMU extracted once per content, "
            "against extracted anew for each run (the baseline, same run).",
            f"A build of an FMU already built from the same sources takes {copied / built:.3f}x a build "
            "(the baseline, same run): a copy from the nfal cache.",
            _slow_plant_finding(*result["slow_plant"].values()),
            *(_c_host_finding(name, *modes.values()) for name, modes in result["c_host_cpu_s"].items())]


def _slow_plant_finding(python: dict, compiled: dict) -> str:
    def ratio(key: str) -> float:
        return np.median(python[key]) / np.median(compiled[key])
    return (f"A 10 ms SlowPlant run with its stop time declared costs {ratio('cpu_s'):.2f}x the CPU of one that "
            f"compiles its kernels at set-up (the baseline, same run); a step in Python takes {ratio('step_s'):.0f}x "
            "a compiled one.")


def _c_host_finding(name: str, one: list[float], per_core: list[float]) -> str:
    return (f"A 10 ms {name} run in the C host with nothing set up costs {np.median(one) / np.median(per_core):.2f}x "
            "the CPU of one whose host asks for a BLAS thread per core (the baseline, same run).")


if __name__ == "__main__":
    main()
