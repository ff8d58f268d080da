"""The before/after table of docs/controller.md, "On a truth with the rig-like excess damping".

    python bench/identified_design.py                         (from the repository root)
    python bench/identified_design.py --calibration k.json    (a file from `nfal identify` instead)

fig7_slow over the Fig. 9-10 staircase with the emulator's default truth as its plant (eq. 17 and the
rig-like excess damping, ``ssp/rig_truth.ssv``), sensor noise off: first the baseline, the paper's law
(``PAPERS_LAW``: the continuous placement on eq. (6), no lift-off mode, lead or reference zero); then four
Controllers with their defaults ("today's"): the continuous and the sampled placement, each on eq. (6) and
given the damping through a calibration file. IAE ratios are against the baseline of the same run.
Without ``--calibration`` that file is a perfect identification: ``ExcessDamping.rig_like()`` tabulated at
7 heights over 50-200 um. ``--no-lag`` makes the transducer and analog filter transparent and turns the lead
off (what is left of the overshoot is then the design's own).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import record
from loop_agreement import run

from nfal.apps.build import build_all
from nfal.apps.fig7 import PURE_LOOP_PARAMETERS, loop_metrics
from nfal.cli.commands.cosim import parse_parameter
from nfal.apps.fig7_names import PAPERS_LAW
from nfal.models.calibration import RigCalibration, paper_calibration, rig_record
from nfal.models.reference import Staircase
from nfal.models.damping import DampingCorrection
from nfal.models.plant import RIG_LIKE_EXCESS_EXPONENT, RIG_LIKE_EXCESS_HEIGHT, ExcessDamping
from nfal.models.rig import RigParameters
from nfal.models.table2 import NOISE_PEAK_M

TRUTH = {"Plant.excess_damping_height": RIG_LIKE_EXCESS_HEIGHT,
         "Plant.excess_damping_exponent": RIG_LIKE_EXCESS_EXPONENT, "SensorChain.noise_peak": 0.0}


def perfect_identification(path: Path) -> Path:
    """The truth's damping factor tabulated at 7 heights over 50-200 um, as a calibration file."""
    heights = np.linspace(50e-6, 200e-6, 7)
    damping = DampingCorrection(heights, ExcessDamping.rig_like().factor(heights))
    RigCalibration(paper_calibration(), damping, rig_record(RigParameters())).save(path)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--calibration", type=Path, help="calibration file (default: a perfect identification)")
    parser.add_argument("--no-lag", action="store_true", help="transducer and analog filter transparent")
    parser.add_argument("--param", action="append", default=[], metavar="ELEMENT.VAR=VALUE",
                        help="set a parameter of the four Controllers of today's law (not the baseline), repeatable")
    parser.add_argument("--levels", type=float, nargs="+", help="staircase levels [m] (default: Figs. 9-10's)")
    parser.add_argument("--hold", type=float, default=0.6, help="hold of each level [s] (default 0.6)")
    parser.add_argument("--noise-seed", type=int, metavar="SEED",
                        help="sensor noise on (Table 2's 2 um peak) with this seed, and the noise RMS of each level "
                        "printed")
    args = parser.parse_args()
    reference = Staircase(tuple(args.levels), hold_s=args.hold) if args.levels else Staircase()
    extra_parameters = dict(parse_parameter(text) for text in args.param)
    with tempfile.TemporaryDirectory() as tmp:
        calibration = args.calibration or perfect_identification(Path(tmp) / "identified.json")
        archive = build_all(f"{tmp}/build", structures=("fig7_slow",))["fig7_slow"]
        noise = ({} if args.noise_seed is None
                 else {"SensorChain.noise_peak": NOISE_PEAK_M, "SensorChain.seed": args.noise_seed})
        truth = {**TRUTH, **(PURE_LOOP_PARAMETERS if args.no_lag else {}), **noise}
        rows = [("continuous", "eq. (6)", "paper's", PAPERS_LAW)]
        for placement in ("continuous", "sampled"):
            for damping, extra in (("eq. (6)", {}), ("identified", {"Controller.calibration": str(calibration)})):
                rows.append((placement, damping, "today's",
                             {"Controller.placement": placement, **extra, **extra_parameters}))
        baseline, measured = None, []
        for number, (placement, damping, law, parameters) in enumerate(rows):
            result = run(archive, f"{tmp}/{number}", reference, parameters={**truth, **parameters})
            metrics = loop_metrics(result.table(), reference)
            baseline = baseline or metrics["iae"]
            measured.append({"placement": placement, "damping": damping, "law": law, "iae_m_s": metrics["iae"],
                             "ratio": metrics["iae"] / baseline,
                             "steps": [{key: step[key] for key in ("overshoot_percent", "settling_time_s",
                                                                   "noise_rms_m")} for step in metrics["steps"]]})
            print(measured[-1], flush=True)
    result = {"noise": args.noise_seed is not None, "rows": measured}
    print(record.save("identified-design", result))
    record.show(tables(result))


def title(result: dict) -> str:
    return "On a truth with the rig-like excess damping: the paper's law and today's, by placement and damping model"


def tables(result: dict) -> list[record.Table]:
    columns = ["placement", "damping", "law", "IAE [µm s]", "ratio (to the paper's law)", "overshoot % per step",
               "2 % settling [ms]"] + (["noise RMS per level [nm] (true height)"] if result["noise"] else [])
    rows = []
    for row in result["rows"]:
        steps = row["steps"]
        cells = [row["placement"], row["damping"], row["law"], f"{row['iae_m_s'] * 1e6:.3f}", f"{row['ratio']:.2f}",
                 ", ".join(f"{step['overshoot_percent']:.1f}" for step in steps),
                 ", ".join(f"{(step['settling_time_s'] or float('nan')) * 1e3:.0f}" for step in steps)]
        if result["noise"]:
            cells.append(", ".join(f"{step['noise_rms_m'] * 1e9:.0f}" for step in steps))
        rows.append(cells)
    return [record.Table("", columns, rows)]

if __name__ == "__main__":
    main()
