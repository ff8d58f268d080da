"""Crashes of our FMUs in non-Python hosts, the numbers docs/cosimulation.md ("Crash at exit") quotes.

    python bench/host_compat.py                    (from the repository root: 100 C-host runs of each
                                                    Fig. 7 FMU, 50 ecos runs of the Fig. 7 archive)
    python bench/host_compat.py --runs 30 --ecos-runs 0 --stock-runtime
                                                   (the same FMUs on pythonfmu 0.7.0's own runtime)
    python bench/host_compat.py --fmi 3            (the FMI 3.0 builds in fmus/hosts/fmi3_host.c; there is
                                                    no FMI 3.0 archive: bench/ecos_exit_codes.py --fmi 3 runs
                                                    each FMU in ecos; --stock-runtime: pythonfmu3 0.3.4's)

Prints, per FMU, the runs, the crashes (exit code not 0) and the runs whose outputs differ from
FMPy's (relative 1e-12); for ecos, the crashes and the largest difference of the drive voltage from
our orchestrator's Jacobi run (ecos writes 6 decimals).
"""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

import numpy as np
import pythonfmu
from fmpy import simulate_fmu

import pythonfmu3
from nfal.build import structure_sources
from nfal.fmus.build import build_fmus
from nfal.host_check import compile_c_host, ecos_executable, run_in_c_host, run_in_ecos
from nfal.orchestration import run_structure
from nfal.orchestration.ssp_archive import pack

FIG7_FMUS = ["SlowPlant", "ReynoldsPlant", "Controller", "ResonanceTracker", "SensorChain"]
#: The builders' own runtimes, per FMI version.
STOCK_RUNTIMES = {2: Path(pythonfmu.__file__).parent / "resources" / "binaries" / "linux64" / "libpythonfmu-export.so",
                  3: Path(pythonfmu3.__file__).parent / "resources" / "binaries" / "x86_64-linux" / "libpythonfmu-export.so"}


def c_host_runs(fmus: dict, folder: Path, runs: int, stop_s: float, stock: bool, fmi_version: int) -> None:
    host = compile_c_host(folder, fmi_version)
    for name in FIG7_FMUS:
        result = run_in_c_host(host, fmus[name], folder / "c", runs=runs, stop_time=stop_s,
                               runtime=STOCK_RUNTIMES[fmi_version] if stock else None)
        reference = simulate_fmu(str(fmus[name]), stop_time=stop_s, step_size=5e-4, output_interval=5e-4)
        differing = sum(any(not math.isclose(value, float(reference[output][-1]), rel_tol=1e-12, abs_tol=0)
                            for output, value in outputs.items()) for outputs in result.outputs)
        print(f"C host  FMI {fmi_version}.0  {name:17s} runs {runs:4d}  crashes {result.crashes:3d}  exit codes "
              f"{sorted(set(result.exit_codes))}  results differing from FMPy's {differing}")


def ecos_runs(fmus: dict, folder: Path, runs: int, stop_s: float) -> None:
    archive = pack(structure_sources() / "fig7_slow.ssd", fmus["SlowPlant"].parent, folder / "fig7_slow.ssp")
    result = run_in_ecos(ecos_executable(folder), archive, folder / "ecos", runs=runs, stop_time=stop_s)
    ours = run_structure(archive, stop_time=stop_s, algorithm="jacobi", out_dir=folder / "ours", plot=False,
                         progress=False)["Controller.drive_voltage"]
    worst = max((np.max(np.abs(np.array(o["ResonanceTracker::drive_voltage"]) - ours[:len(o["time"])]))
                 for o in result.outputs), default=float("nan"))
    print(f"ecos    fig7_slow.ssp     runs {runs:4d}  crashes {result.crashes:3d}  exit codes "
          f"{sorted(set(result.exit_codes))}  max |drive voltage - ours| {worst:.2g} V over {stop_s} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=100, help="C-host runs per FMU (default 100)")
    parser.add_argument("--stop-time", type=float, default=0.01, help="C-host stop time [s] (default 0.01)")
    parser.add_argument("--ecos-runs", type=int, default=50, help="ecos runs of the Fig. 7 archive (default 50)")
    parser.add_argument("--ecos-stop-time", type=float, default=1.0, help="ecos stop time [s] (default 1)")
    parser.add_argument("--stock-runtime", action="store_true", help="run the C host on pythonfmu's own runtime")
    parser.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version of the builds (default 2)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="nfal_host_compat_") as temp:
        folder = Path(temp)
        fmus = build_fmus(folder / "fmus", FIG7_FMUS, fmi_version=args.fmi)
        if args.runs:
            c_host_runs(fmus, folder, args.runs, args.stop_time, args.stock_runtime, args.fmi)
        if args.ecos_runs and args.fmi == 2:
            ecos_runs(fmus, folder, args.ecos_runs, args.ecos_stop_time)


if __name__ == "__main__":
    main()
