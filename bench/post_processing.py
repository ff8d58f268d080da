"""What `nfal run` does after a long loop, timed: the results read back, the Fig. 7 loop's metrics and checks, the plot.

    python bench/post_processing.py [--csv FILE] [--duration 600]

The file is the results.csv of a long HIL run (``python bench/realtime.py hil --duration 600`` writes one; default:
the newest under runs/), whose reference is that bench's staircase over ``--duration`` s. Each stage runs as
``nfal run`` runs it after its loop, in this process; its wall time is given with its ratio to reading the file back
(the baseline, same run: what any use of the file costs at least). Writes bench/results/post-processing.json.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import record
from realtime import HERE, hil_staircase

from nfal.apps.fig7 import (HARDWARE, HARDWARE_LEAD_S, loop_checks, loop_metrics, reference_staircase,
                            response_panels, step_reference)
from nfal.orchestration.results import plot_response, read_results


def newest_hil_results() -> Path | None:
    found = sorted(HERE.parent.glob("runs/realtime-hil-*/hil/results.csv"), key=lambda path: path.stat().st_mtime)
    return found[-1] if found else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--csv", type=Path, help="a long HIL run's results.csv (default: the newest under runs/)")
    parser.add_argument("--duration", type=float, default=600.0, help="the run's length [s] (default 600)")
    args = parser.parse_args()
    path = args.csv or newest_hil_results()
    if path is None or not path.is_file():
        parser.error("no results.csv: give --csv, or run `python bench/realtime.py hil --duration 600` first")
    steps, _ = step_reference(reference_staircase(hil_staircase(args.duration), "fig7_hil", HARDWARE_LEAD_S),
                              0.0, args.duration)
    seconds = {}
    started = time.perf_counter()
    table = read_results(path)
    seconds["read"] = time.perf_counter() - started
    with tempfile.TemporaryDirectory() as folder:
        stages = {"metrics": lambda: loop_metrics(table, steps, HARDWARE),
                  "checks": lambda: loop_checks(table, steps, HARDWARE),
                  "plot": lambda: plot_response(table, Path(folder) / "response.png", response_panels(HARDWARE))}
        for name, stage in stages.items():
            started = time.perf_counter()
            stage()
            seconds[name] = time.perf_counter() - started
    result = {"rows": len(table), "file_mb": round(path.stat().st_size / 1e6, 1), "seconds": seconds}
    print(record.save("post-processing", result, argv=["--csv", str(path), "--duration", f"{args.duration:g}"]))
    record.show(tables(result), findings(result))


def tables(result: dict) -> list[record.Table]:
    read = result["seconds"]["read"]
    return [record.Table(f"A results.csv of {result['rows']} rows, {result['file_mb']} MB:",
                         ["stage", "wall time [s]", "ratio to reading the file"],
                         [[stage, f"{wall:.2f}", f"{wall / read:.2f}"] for stage, wall in result["seconds"].items()])]


def findings(result: dict) -> list[str]:
    seconds = result["seconds"]
    return [f"After the loop, `nfal run` takes about {sum(seconds.values()):.1f} s over a run of this length, "
            f"{seconds['read'] / sum(seconds.values()):.0%} of it reading the file back."]


if __name__ == "__main__":
    main()
