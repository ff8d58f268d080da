"""Exit codes of the ecos command line (ecospy 0.7.2, a non-Python host) running each FMU alone, N times.

    python bench/ecos_exit_codes.py [--runs N] [--fmi 2 3] [--out DIR]

Builds the FMUs (FMI 2.0 and FMI 3.0, ``nfal build``), then runs ``ecos simulate`` on each (0.01 s at
0.5 ms, ``host_check.run_in_ecos``) with nothing set up (``env -i PATH=/usr/bin:/bin HOME=$HOME``), and prints
a markdown table of exit codes per FMU: 0 is a clean exit, -11 a segmentation fault (issue 15, item 1: the
embedded interpreter's teardown). The HardwareProxy is left out (it needs a rig). Needs ecospy and Debian's
libtbb12.
"""

from __future__ import annotations

import argparse
import collections
import tempfile
from pathlib import Path

import record

from nfal.fmus.build import FMU_SCRIPTS, build_fmus
from nfal.apps.host_check import ecos_executable, run_in_ecos

FMUS = [name for name in FMU_SCRIPTS if name != "HardwareProxy"]


def exit_codes(ecos: Path, fmu: Path, runs: int) -> collections.Counter:
    with tempfile.TemporaryDirectory() as work:
        return collections.Counter(run_in_ecos(ecos, fmu, Path(work), runs=runs, stop_time=0.01).exit_codes)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=10, help="runs per FMU (default 10)")
    parser.add_argument("--fmi", type=int, nargs="+", choices=(2, 3), default=[2, 3], help="FMI versions (default 2 3)")
    parser.add_argument("--out", type=Path, help="build folder (default: a temporary one)")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as temp:
        out = args.out or Path(temp)
        ecos = ecos_executable(Path(temp))
        for version in args.fmi:
            built = build_fmus(out / f"fmi{version}", FMUS, fmi_version=version)
            for name, fmu in built.items():
                codes = exit_codes(ecos, fmu, args.runs)
                rows.append({"fmu": name, "fmi": version, "runs": args.runs,
                             "exit_codes": {str(code): n for code, n in sorted(codes.items())}})
                print(rows[-1], flush=True)
    result = {"rows": rows}
    print(record.save("ecos-exit-codes", result))
    record.show(tables(result))


def tables(result: dict) -> list[record.Table]:
    def cells(row: dict) -> list:
        codes = {int(code): n for code, n in row["exit_codes"].items()}
        other = sum(n for code, n in codes.items() if code not in (0, -11))
        return [row["fmu"], f"{row['fmi']}.0", row["runs"], codes.get(0, 0), codes.get(-11, 0), other]
    return [record.Table("", ["FMU", "FMI", "runs", "clean exits", "crashes at exit (SIGSEGV)", "other"],
                         [cells(row) for row in result["rows"]])]

if __name__ == "__main__":
    main()
