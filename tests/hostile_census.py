"""A census of hostile and careless input: every command, file format, FMU and the rig link, classified.

The cases and how an outcome is judged are in tests/hostile_cases.py (the test suite runs one case per
class of issue 18 from the same list, tests/test_hostile_inputs.py); this runs all of them, one process
each, and prints the counts that docs/hostile_inputs.md quotes. Run from the repository (about 15 minutes
on 2 cores)::

    python tests/hostile_census.py                  # every case; the counts and the cases not clear/handled
    python tests/hostile_census.py --only fmu --list
    python tests/hostile_census.py --json census.json
"""

from __future__ import annotations

import argparse
import collections
import concurrent.futures
import dataclasses
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from hostile_cases import CLEAR, CRASH, HANDLED, OUTCOMES, REFUSED, TRACEBACK, WRONG, all_cases, run_case


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", metavar="TEXT", help="only the cases whose id or area contains TEXT")
    parser.add_argument("--list", action="store_true", help="print every case's outcome, not only the bad ones")
    parser.add_argument("--json", metavar="FILE", help="write every outcome to FILE")
    parser.add_argument("--jobs", type=int, default=1, help="cases run at once (default 1; each is its own process)")
    parser.add_argument("--keep", action="store_true", help="keep the case folders (printed)")
    args = parser.parse_args(argv)
    cases = [c for c in all_cases() if not args.only or args.only in c.id or args.only in c.area]
    if os.geteuid() == 0:
        skipped = [c.id for c in cases if c.needs_permissions]
        cases = [c for c in cases if not c.needs_permissions]
        print(f"running as root: {len(skipped)} read-only-folder cases skipped ({', '.join(skipped)})")
    ids = collections.Counter(c.id for c in cases)
    assert max(ids.values()) == 1, [i for i, n in ids.items() if n > 1]
    root = Path(tempfile.mkdtemp(prefix="nfal-census-"))
    build = root / "_build"
    subprocess.run([sys.executable, "-m", "nfal", "build", "--out", str(build)], check=True, capture_output=True)
    outcomes = []
    start = time.perf_counter()
    try:
        with concurrent.futures.ThreadPoolExecutor(args.jobs) as pool:
            for number, outcome in enumerate(pool.map(lambda case: run_case(case, root, build), cases), 1):
                outcomes.append(outcome)
                if args.list or outcome.outcome not in (CLEAR, HANDLED):
                    print(f"[{number}/{len(cases)}] {outcome.outcome:15} {outcome.case}: {outcome.detail}", flush=True)
    finally:
        for path in root.rglob("*"):  # read-only folders made by the set-ups
            if path.is_dir() and not path.is_symlink():
                path.chmod(0o755)
        if not args.keep:
            shutil.rmtree(root, ignore_errors=True)
    counts = collections.Counter(o.outcome for o in outcomes)
    print(f"\n{len(outcomes)} cases in {time.perf_counter() - start:.0f} s: "
          + ", ".join(f"{counts[name]} {name}" for name in OUTCOMES))
    by_area = collections.defaultdict(collections.Counter)
    for o in outcomes:
        by_area[o.area][o.outcome] += 1
    for area, c in sorted(by_area.items()):
        print(f"  {area:14} " + ", ".join(f"{c[name]} {name}" for name in OUTCOMES if c[name]))
    if args.json:
        Path(args.json).write_text(json.dumps([dataclasses.asdict(o) for o in outcomes], indent=1))
    if args.keep:
        print(f"case folders: {root}")
    return 0 if counts[TRACEBACK] + counts[CRASH] + counts[WRONG] + counts[REFUSED] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
