"""What the ecos command line (ecospy's libcosim, a non-Python host) costs to run fig7_slow's whole staircase, against
``nfal run`` of the same archive with the same algorithm (libcosim's fixed-step Jacobi), each in a process of its own.

    python bench/ecos_cost.py [--runs N] [--out DIR]

Builds fig7_slow.ssp (``nfal build``), then runs, alternately, ``ecos simulate`` (3.7 s at 0.5 ms, with nothing set up:
``host_check.run_in_ecos``) and ``python -m nfal run --algorithm jacobi --no-plot`` on it, N times each, and records
each run's wall time and CPU (user and system, the process and its children). ecos calls the FMUs from threads of its
own, where every call once made a new Python thread state (the runtimes' ``py_safe_run``). Needs ecospy and
Debian's libtbb12.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import record

from nfal.apps.build import build_all
from nfal.apps.host_check import ecos_executable, run_in_ecos

STOP_S = 3.7


def measured(run) -> dict:
    """Run ``run()`` (which waits for its processes); the wall time and its children's user and system CPU [s]."""
    before, started = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    run()
    wall, after = time.perf_counter() - started, resource.getrusage(resource.RUSAGE_CHILDREN)
    return {"wall_s": wall, "user_s": after.ru_utime - before.ru_utime, "system_s": after.ru_stime - before.ru_stime}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=3, help="runs of each host (default 3)")
    parser.add_argument("--out", type=Path, help="build folder (default: a temporary one)")
    args = parser.parse_args()
    runs = {"ecos": [], "nfal run": []}
    with tempfile.TemporaryDirectory() as temp:
        archive = build_all(args.out or Path(temp) / "build", structures=("fig7_slow",))["fig7_slow"]
        ecos = ecos_executable(Path(temp) / "ecos")
        for k in range(args.runs):
            work = Path(temp) / f"run{k}"

            def in_ecos() -> None:
                done = run_in_ecos(ecos, archive, work / "ecos", runs=1, stop_time=STOP_S)
                if done.exit_codes != [0]:
                    raise SystemExit(f"ecos failed: {done.first_failure[-2000:]}")

            def in_nfal() -> None:
                subprocess.run([sys.executable, "-m", "nfal", "run", str(archive), "--algorithm", "jacobi",
                                "--no-plot", "--out", str(work / "nfal")], check=True, capture_output=True)

            for host, run in (("ecos", in_ecos), ("nfal run", in_nfal)):
                runs[host].append(measured(run))
                print(host, runs[host][-1], flush=True)
    result = {"stop_s": STOP_S, "runs": runs}
    print(record.save("ecos-cost", result))
    record.show(tables(result))


def tables(result: dict) -> list[record.Table]:
    baseline = statistics.median(run["user_s"] + run["system_s"] for run in result["runs"]["nfal run"])

    def cells(host: str) -> list:
        runs = result["runs"][host]
        cpu = [run["user_s"] + run["system_s"] for run in runs]
        span = lambda values: f"{min(values):.2f}-{max(values):.2f}"  # noqa: E731
        return [host, len(runs), span([run["wall_s"] for run in runs]), span([run["user_s"] for run in runs]),
                span([run["system_s"] for run in runs]), f"{statistics.median(cpu) / baseline:.2f}"]
    return [record.Table(f"fig7_slow.ssp, its whole staircase ({result['stop_s']:g} s at 0.5 ms), each run in a "
                         "process of its own:", ["host", "runs", "wall [s]", "user CPU [s]", "system CPU [s]",
                                                 "CPU / nfal run's (medians)"],
                         [cells(host) for host in result["runs"]])]


if __name__ == "__main__":
    main()
