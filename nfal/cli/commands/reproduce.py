"""``nfal reproduce``: the paper's tables and figures in one command, each number beside the paper's."""

from __future__ import annotations

import argparse
import datetime
from pathlib import Path

from nfal.apps.figures.reproduce import shown
from nfal.apps.reproduce import SECTIONS, reproduce
from nfal.cli.commands import COMMANDS
from nfal.cli.commands.common import print_json, progress_bar
from nfal.errors import ResultsExistError

#: The files of a report (refused in --out unless --overwrite).
REPORT_FILES = ("report.html", "report.json")


def register(commands) -> None:
    reproduce = commands.add_parser(
        "reproduce", help=COMMANDS["reproduce"].summary,
        description="Regenerate every table and figure of the paper that the models produce: Fig. 4 (K numerically "
        "and from measured equilibria, against eq. 17), Table 1 and Fig. 5, Fig. 6 (constant excitations on the "
        "emulated rig against eq. 13), Fig. 8, Figs. 9-10 (the paper's law simulated) and the analogue of Figs. "
        "11-12 (the same controllers against the rig emulator, over the rig protocol, in lockstep, 35 Hz "
        "low-pass). Writes DIR/report.html (open it in a browser), DIR/report.json (every number, the paper's "
        "beside it, the tolerance and whether it holds) and the PNGs. The paper's numbers come from one data file, "
        "models/data/paper_numbers.json (nfal/models/data/ where nfal is installed). Exit status 0 when every "
        "judged number holds or differs only where "
        "the report explains why (a known difference), 1 otherwise.",
        epilog="About a minute on a 2-core machine (the rig runs and Table 1's full-model runs are most of it); the "
        "first run also builds the FMUs and fills the cache (about 100 s). Example: nfal reproduce --out runs/paper "
        "&& xdg-open runs/paper/report.html")
    reproduce.add_argument("--out", metavar="DIR", help="the report's folder (default runs/reproduce-<date-time>)")
    reproduce.add_argument("--overwrite", action="store_true", help="replace a report already in DIR")
    reproduce.add_argument("--quick", action="store_true", help="smaller grids for Fig. 4 and Fig. 8 (the "
                           "simulations and rig runs are the same)")
    reproduce.add_argument("--build-dir", default="build", metavar="DIR",
                           help="where the FMUs and structures are built (default build/)")
    reproduce.add_argument("--json", action="store_true", help="print report.json on stdout")
    reproduce.set_defaults(handler=run_reproduce)


def run_reproduce(args: argparse.Namespace) -> int:
    out = Path(args.out or Path("runs") / f"reproduce-{datetime.datetime.now():%Y%m%d-%H%M%S}")
    existing = [name for name in REPORT_FILES if (out / name).exists()]
    if existing and not args.overwrite:
        raise ResultsExistError(f"{out} already holds a report ({', '.join(existing)}): choose another --out, or "
                                "--overwrite")
    with progress_bar(sum(units for _, _, units in SECTIONS), "reproducing the paper") as bar:
        def advance(units: int, name: str) -> None:
            bar.set_postfix_str(name)
            bar.update(units)

        report = reproduce(out, quick=args.quick, build_dir=args.build_dir, progress=advance)
    if args.json:
        print_json(report.to_dict())
    else:
        _print_summary(report)
    return 1 if report.unexpected else 0


def _print_summary(report) -> None:
    for section in report.sections:
        print(section.title)
        for c in (c for c in section.comparisons if c.holds is not None):
            unit = f" {c.unit}" if c.unit else ""
            print(f"  {c.key} ({c.paper.where}): {c.paper.what}: paper {c.paper_shown}{unit}, "
                  f"ours {shown(c.ours)}{unit}: {c.verdict}")
    print(f"{report.summary}. Report: {report.out_dir / 'report.html'}")
