"""Crashes of our FMUs in non-Python hosts, the numbers docs/cosimulation.md ("Crash at exit", "The loader") quotes.

Every host runs with nothing set up (``env -i PATH=/usr/bin:/bin HOME=$HOME``, ``host_check.bare_environment``)::

    python bench/host_compat.py --runs 50 --ecos-runs 50 --ecos-stop-time 0.1
                                                   (from the repository root: 50 C-host runs of each Fig. 7
                                                    FMU, 50 ecos runs of the Fig. 7 archive fig7_slow.ssp)
    python bench/host_compat.py --fmi 3 ...        (the FMI 3.0 builds in fmus/hosts/fmi3_host.c, and ecos on
                                                    fig7_slow.ssd packed with them)
    python bench/host_compat.py --environment other-python ...
                                                   (a venv without numpy first on PATH, the host started in
                                                    another folder: the FMUs must run on the Python they recorded)
    python bench/host_compat.py --environment missing-python ...
                                                   (NFAL_FMU_PYTHON names a Python that does not exist: each run
                                                    must log one line naming it and fail, never crash)
    python bench/host_compat.py --runs 30 --ecos-runs 0 --stock-runtime
                                                   (the same FMUs on pythonfmu 0.7.0's own runtime, LD_PRELOAD
                                                    recipe: the stock runtime has no loader)

Prints, per FMU, the runs, the crashes (exit code not 0; with missing-python: killed by a signal) and the
runs whose outputs differ from FMPy's (relative 1e-12); for ecos, the crashes and the largest difference
of the drive voltage from our orchestrator's Jacobi run of the FMI 2.0 archive (ecos writes 6 decimals).
With missing-python: the runs whose output holds the loader's line exactly once.
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import record
from record import report
import pythonfmu
from fmpy import simulate_fmu

import pythonfmu3
from nfal.apps.build import structure_sources
from nfal.fmus.build import SIMULATION_FMUS, build_fmus
from nfal.fmus.export_runtime import PYTHON_OVERRIDE_ENV
from nfal.apps.host_check import (bare_environment, compile_c_host, ecos_executable, fmus_in, run_in_c_host,
                              run_in_ecos)
from nfal.orchestration import run_structure
from nfal.orchestration.libcosim import preload_environment
from nfal.orchestration.ssp_archive import pack

FIG7_FMUS = list(SIMULATION_FMUS)
#: The builders' own runtimes, per FMI version.
STOCK_RUNTIMES = {2: Path(pythonfmu.__file__).parent / "resources" / "binaries" / "linux64" / "libpythonfmu-export.so",
                  3: (Path(pythonfmu3.__file__).parent / "resources" / "binaries" / "x86_64-linux"
                      / "libpythonfmu-export.so")}


ENVIRONMENTS = ("bare", "other-python", "missing-python")


def environment(kind: str, folder: Path) -> tuple[dict[str, str], Path | None, str | None]:
    """The hosts' environment for ``kind``, the working directory (None: the FMU's folder) and the line a
    missing Python must log (None for the other kinds)."""
    if kind == "bare":
        return bare_environment(), None, None
    if kind == "missing-python":
        missing = str(folder / "no" / "python")
        return bare_environment(**{PYTHON_OVERRIDE_ENV: missing}), None, missing
    base = Path("/usr/bin/python3") if Path("/usr/bin/python3").is_file() else Path(sys.base_prefix) / "bin" / "python3"
    venv = folder / "other-venv"
    subprocess.run([str(base), "-m", "venv", "--without-pip", str(venv)], check=True)
    elsewhere = folder / "elsewhere"
    elsewhere.mkdir()
    return bare_environment(PATH=f"{venv / 'bin'}:/usr/bin:/bin", VIRTUAL_ENV=str(venv)), elsewhere, None


def c_host_runs(fmus: dict, folder: Path, runs: int, stop_s: float, stock: bool, fmi_version: int, kind: str) -> None:
    host = compile_c_host(folder, fmi_version)
    env, cwd, missing = environment(kind, folder)
    if stock:
        env = preload_environment()
    for name in FIG7_FMUS:
        result = run_in_c_host(host, fmus[name], folder / "c", runs=runs, stop_time=stop_s, env=env, cwd=cwd,
                               runtime=STOCK_RUNTIMES[fmi_version] if stock else None)
        if missing:
            report(f"C host  FMI {fmi_version}.0  {name:17s} runs {runs:4d}  killed by a signal {result.signals:3d}  "
                  f"exit codes {sorted(set(result.exit_codes))}  one line naming the missing Python "
                  f"{result.logged_once(missing)}")
            continue
        reference = simulate_fmu(str(fmus[name]), stop_time=stop_s, step_size=5e-4, output_interval=5e-4)
        differing = sum(any(not math.isclose(value, float(reference[output][-1]), rel_tol=1e-12, abs_tol=0)
                            for output, value in outputs.items()) for outputs in result.outputs)
        report(f"C host  FMI {fmi_version}.0  {name:17s} runs {runs:4d}  crashes {result.crashes:3d}  exit codes "
              f"{sorted(set(result.exit_codes))}  results differing from FMPy's {differing}")


def ecos_runs(fmus: dict, fmus2: dict, folder: Path, runs: int, stop_s: float, fmi_version: int, kind: str) -> None:
    env, _, missing = environment(kind, folder / "ecos-env")
    archive = pack(structure_sources() / "fig7_slow.ssd", fmus["SlowPlant"].parent,
                   folder / f"fig7_slow_fmi{fmi_version}.ssp")
    result = run_in_ecos(ecos_executable(folder), archive, folder / "ecos", runs=runs, stop_time=stop_s, env=env)
    if missing:
        report(f"ecos    FMI {fmi_version}.0  fig7_slow.ssp runs {runs:4d}  killed by a signal {result.signals:3d}  "
              f"exit codes {sorted(set(result.exit_codes))}  one line per FMU naming the missing Python "
              f"{result.logged_once(missing, fmus_in(archive))}")
        return
    reference = pack(structure_sources() / "fig7_slow.ssd", fmus2["SlowPlant"].parent, folder / "fig7_slow_ours.ssp")
    ours = run_structure(reference, stop_time=stop_s, algorithm="jacobi", out_dir=folder / "ours", plot=False,
                         progress=False)["Controller.drive_voltage"]
    worst = max((np.max(np.abs(np.array(o["ResonanceTracker::drive_voltage"]) - ours[:len(o["time"])]))
                 for o in result.outputs), default=float("nan"))
    report(f"ecos    FMI {fmi_version}.0  fig7_slow.ssp runs {runs:4d}  crashes {result.crashes:3d}  exit codes "
          f"{sorted(set(result.exit_codes))}  max |drive voltage - ours (FMI 2.0, Jacobi)| {worst:.2g} V "
          f"over {stop_s} s")

def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=100, help="C-host runs per FMU (default 100)")
    parser.add_argument("--stop-time", type=float, default=0.01, help="C-host stop time [s] (default 0.01)")
    parser.add_argument("--ecos-runs", type=int, default=50, help="ecos runs of the Fig. 7 archive (default 50)")
    parser.add_argument("--ecos-stop-time", type=float, default=1.0, help="ecos stop time [s] (default 1)")
    parser.add_argument("--stock-runtime", action="store_true", help="run the C host on pythonfmu's own runtime")
    parser.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version of the builds (default 2)")
    parser.add_argument("--environment", choices=ENVIRONMENTS, default="bare",
                        help="what the hosts run in (default: bare, nothing set up)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="nfal_host_compat_") as temp:
        folder = Path(temp)
        fmus = build_fmus(folder / "fmus", FIG7_FMUS, fmi_version=args.fmi)
        if args.runs:
            c_host_runs(fmus, folder, args.runs, args.stop_time, args.stock_runtime, args.fmi, args.environment)
        if args.ecos_runs:
            fmus2 = fmus if args.fmi == 2 else build_fmus(folder / "fmus2", FIG7_FMUS)
            (folder / "ecos-env").mkdir()
            ecos_runs(fmus, fmus2, folder, args.ecos_runs, args.ecos_stop_time, args.fmi, args.environment)

    variant = f"host-compat-fmi{args.fmi}-{args.environment}" + ("-stock-runtime" if args.stock_runtime else "")
    print(record.save(variant, {"variant": variant, "lines": record.LINES}))

if __name__ == "__main__":
    main()
