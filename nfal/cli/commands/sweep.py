"""``nfal sweep``: many runs (SSP runs with overrides, K(sigma) calibrations, Table-1 cases) on Dask."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from nfal.apps.build import DEFAULT_BUILD_DIR, STRUCTURES, build_all
from nfal.apps.sweeps import load_spec
from nfal.cli.commands import COMMANDS
from nfal.cli.commands.common import add_accept_long_plan, duration_text, print_json, refuse_given
from nfal.errors import InvalidParameterError, PlanError
from nfal.orchestration.sweep import run_sweep

#: The longest sweep run without --accept-long-plan: this many runs, and SSP runs simulating this long in all [s]
#: (fig7_slow takes about 2 s of a worker per simulated second: examples/sweeps/robustness.toml, 12 runs of 0.4 s).
LONG_SWEEP_RUNS = 1_000
LONG_SWEEP_SIMULATED_S = 3600.0


def register(commands) -> None:
    sweep = commands.add_parser(
        "sweep", help=COMMANDS["sweep"].summary,
        description="Expand SPEC.toml into runs (an SSP run with parameter overrides, a K(sigma) calibration or a "
        "Table-1 case, over a [grid] and/or seeded [random] draws) and run them on Dask: a local cluster on this "
        "machine's cores, or the scheduler at --scheduler (no shared file system needed: archives are shipped once "
        "per worker and checked by sha256). Each finished run is appended to DIR/results.csv (a failed run is a row "
        "with its error); re-running the same spec into the same DIR skips finished runs. Writes summary.json and "
        "sweep.png at the end.",
        epilog="Examples: nfal sweep examples/sweeps/robustness.toml; "
        "nfal sweep examples/sweeps/k_sigma.toml --workers 2 --out runs/k; "
        "nfal sweep spec.toml --scheduler tcp://10.0.0.5:8786")
    sweep.add_argument("spec", metavar="SPEC.toml",
                       help="the sweep spec (see docs in README 'Sweep many runs on Dask')")
    sweep.add_argument("--scheduler", metavar="ADDRESS", help="a running Dask scheduler, e.g. tcp://host:8786 "
                       "(default: a local cluster)")
    sweep.add_argument("--workers", type=int, metavar="N", help="worker processes of the local cluster, not with "
                       "--scheduler (default: this machine's cores); 0: the runs one after another in this process, "
                       "without Dask (for debugging)")
    sweep.add_argument("--out", metavar="DIR", help="result folder (default runs/sweep-<spec name>); continued if it "
                       "holds the same spec's table")
    sweep.add_argument("--build-dir", metavar="DIR", help="where built-in structures (fig7_slow, fig7_reynolds) are "
                       "built (default build/); only for a spec that runs one")
    sweep.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_accept_long_plan(sweep, f"{LONG_SWEEP_RUNS:,} runs, or SSP runs simulating more than "
                         f"{duration_text(LONG_SWEEP_SIMULATED_S)} in all (runs x the time each simulates; fig7_slow "
                         "takes about 2 s of a worker per simulated second)")
    sweep.set_defaults(handler=run_sweep_command)


def run_sweep_command(args: argparse.Namespace) -> int:
    if args.workers is not None and args.workers < 0:
        raise InvalidParameterError("--workers", args.workers, "a whole number >= 0 (0: in this process)")
    if args.scheduler:
        refuse_given({"--workers": args.workers}, "with --scheduler (the scheduler's own workers run the sweep)")
    spec = load_spec(args.spec)
    builds = spec.kind.needs_archive and spec.settings["structure"] in STRUCTURES
    if not builds:
        refuse_given({"--build-dir": args.build_dir}, f"with {args.spec}: it runs no built-in structure "
                     f"({', '.join(STRUCTURES)})")
    if not args.accept_long_plan:
        _require_short(spec, args.spec)
    if not getattr(args, "verbose", False):  # Dask's scheduler and nanny log every connection at INFO
        import distributed  # noqa: F401 - configures its loggers on import; quiet them afterwards

        for name in [n for n in logging.root.manager.loggerDict if n.split(".")[0] == "distributed"] + ["distributed"]:
            logging.getLogger(name).setLevel(logging.ERROR)
    archives = None
    if builds:
        archives = build_all(args.build_dir or DEFAULT_BUILD_DIR, structures=(spec.settings["structure"],))
    out = Path(args.out) if args.out else Path("runs") / f"sweep-{spec.name}"
    result = run_sweep(spec, out, scheduler=args.scheduler, workers=args.workers, archives=archives)
    summary = result.summary
    if args.json:
        print_json(summary | {"results_csv": str(result.csv_path),
                              "plot": str(result.plot_path) if result.plot_path else None})
        return 0 if summary["failed"] == 0 else 1
    warned = summary["with_warnings"]
    where = (f" in {summary['wall_time_s']:.1f} s on {summary['workers']} workers ({summary['scheduler']})"
             if summary["new"] else "")
    print(f"{spec.name}: {summary['runs']} runs ({summary['skipped']} already done, {summary['new']} run now){where}: "
          f"{summary['ok']} ok{f' ({warned} with warnings)' if warned else ''}, {summary['failed']} failed "
          f"-> {result.csv_path}")
    if result.plot_path:
        print(f"plot: {result.plot_path}")
    if summary["failed"] or warned:
        for row in result.rows():
            if row["status"] != "ok":
                print(f"  failed {row['run_id']}: {row['error']}")
            elif row.get("warnings"):
                print(f"  warning {row['run_id']}: {row['warnings']}")
    return 0 if summary["failed"] == 0 else 1


def _require_short(spec, source: str) -> None:
    """Refuse a sweep longer than LONG_SWEEP_RUNS runs or LONG_SWEEP_SIMULATED_S simulated, with its length."""
    runs, simulated = spec.length()
    if runs > LONG_SWEEP_RUNS or (simulated or 0.0) > LONG_SWEEP_SIMULATED_S:
        length = f"{runs:,} runs" + (f" simulating {simulated:,.0f} s in all" if simulated else "")
        raise PlanError(f"{source}: {length}, more than {LONG_SWEEP_RUNS:,} runs or {LONG_SWEEP_SIMULATED_S:,.0f} s "
                        "simulated: give --accept-long-plan to run it, or fewer grid values or draws")
