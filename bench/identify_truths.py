"""How well ``nfal identify`` recovers rigs it was not designed for (issue 14): run the emulator with a given truth
on a pty, identify it over the rig protocol, and compare with the truth's known parameters.

    python bench/identify_truths.py                 # every case below
    python bench/identify_truths.py default mass    # some of them

For each case: the largest error of the identified model's equilibrium heights against the truth's over 50-200 um
(at the drive voltages that hold the truth at 41 heights there; both by eq. (16)), the largest error of the
identified damping factor against the truth's 1 + (h / H)^n at every identified height, and the rig time. The
emulator runs with a 0.2 s watchdog, since this 2-core machine stalls the host for more than 20 ms under load.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import record

from nfal.errors import NfalError
from nfal.models.calibration import (PAPER_SIGMA_RANGE, TabulatedK, calibration_from_dict, load_calibration,
                                     paper_calibration)
from nfal.models.plant import RIG_LIKE_EXCESS_EXPONENT, RIG_LIKE_EXCESS_HEIGHT, ExcessDamping, SimplifiedPlant
from nfal.models.rig import RigParameters

METRES_PER_VOLT = 1e-7


def tilted_calibration(path: Path) -> Path:
    """A truth K that is not a quartic: eq. (17) times 0.85 + 0.3 exp(-sigma / 80), as a table."""
    sigma = np.geomspace(*PAPER_SIGMA_RANGE, 200)
    TabulatedK(sigma, paper_calibration()(sigma) * (0.85 + 0.3 * np.exp(-sigma / 80)),
               name="tilted eq. (17)").save(path)
    return path


def cases(folder: Path) -> dict[str, dict]:
    """name -> {mass, excess (height, exponent), calibration (None: eq. 17)}."""
    rig_like = (RIG_LIKE_EXCESS_HEIGHT, RIG_LIKE_EXCESS_EXPONENT)
    return {"default": {"mass": 0.1347, "excess": rig_like, "calibration": None},
            "mass": {"mass": 0.18, "excess": rig_like, "calibration": None},
            "damping-160-4": {"mass": 0.1347, "excess": (160e-6, 4.0), "calibration": None},
            "damping-115-8": {"mass": 0.1347, "excess": (115e-6, 8.0), "calibration": None},
            "calibration": {"mass": 0.1347, "excess": rig_like,
                            "calibration": tilted_calibration(folder / "tilted.json")}}


def truth_parameters(case: dict) -> list[str]:
    """The case's truth as ELEMENT.VAR=VALUE settings of the emulator's rig structure (and of fig7_slow)."""
    height, exponent = case["excess"]
    params = [f"Plant.mass={case['mass']}", f"Plant.excess_damping_height={height}",
              f"Plant.excess_damping_exponent={exponent}"]
    if case["calibration"] is not None:
        params.append(f"Plant.calibration={case['calibration']}")
    return params


def emulator_arguments(case: dict) -> list[str]:
    return [item for p in truth_parameters(case) for item in ("--param", p)]


def identify(case: dict, folder: Path, name: str) -> dict:
    """Run the emulator with the case's truth and ``nfal identify`` against it; the calibration file's content."""
    link = folder / f"{name}.pty"
    emulator = subprocess.Popen([sys.executable, "-m", "nfal", "rig-emulator", "--link", str(link), "--watchdog", "0.2",
                                 *emulator_arguments(case)], stdout=subprocess.PIPE, text=True)
    try:
        emulator.stdout.readline()  # the port: the emulator is up
        out = folder / f"{name}.json"
        started = time.perf_counter()
        subprocess.run([sys.executable, "-m", "nfal", "identify", "--port", str(link), "--out", str(out),
                        "--mass", str(case["mass"])], check=True)
        document = json.loads(out.read_text())
        document["wall_s"] = time.perf_counter() - started
        return document
    finally:
        emulator.terminate()
        emulator.wait(timeout=10)


def compare(case: dict, document: dict) -> dict:
    """Equilibrium-height and damping errors of the identified model against the truth."""
    rig = RigParameters(mass=case["mass"])
    truth_K = paper_calibration() if case["calibration"] is None else load_calibration(case["calibration"])
    truth = SimplifiedPlant(rig, truth_K)
    identified = SimplifiedPlant(rig, calibration_from_dict(document))
    heights = np.linspace(50e-6, 200e-6, 41)
    errors = [identified.equilibrium_height(float(truth.equilibrium_excitation(h))) / h - 1 for h in heights]
    damping = document["damping"]
    truth_factor = ExcessDamping(*case["excess"]).factor(np.array(damping["heights_m"]))
    factor_errors = np.array(damping["factors"]) / truth_factor - 1
    inside = [(lo <= t <= hi) for lo, t, hi in zip(damping["factors_low"], truth_factor, damping["factors_high"])]
    worst = int(np.argmax(np.abs(errors)))
    return {"equilibrium_error_max_percent": 100 * float(np.max(np.abs(errors))),
            "worst_at_um": round(heights[worst] * 1e6),
            "damping_error_max_percent": 100 * float(np.max(np.abs(factor_errors))),
            "damping_errors_percent": [round(100 * e, 1) for e in factor_errors],
            "truth_inside_interval": f"{sum(inside)}/{len(inside)}",
            "rig_time_s": document["provenance"]["rig_time_s"], "wall_s": document["wall_s"]}


def main(names: list[str]) -> None:
    folder = Path("runs") / time.strftime("identify-bench-%Y%m%d-%H%M%S")
    folder.mkdir(parents=True)
    print(f"calibration files, raw data and figures in {folder}", flush=True)
    table = cases(folder)
    results = {}
    for name in names or list(table):
        try:
            results[name] = compare(table[name], identify(table[name], folder, name))
        except subprocess.CalledProcessError as exc:
            results[name] = {"failed": f"nfal identify exited {exc.returncode} (its message is above)"}
        except NfalError as exc:
            results[name] = {"failed": f"the identified model cannot be compared: {exc}"}
        print(name, json.dumps(results[name]), flush=True)
        record.save("identify-truths", {"cases": results})  # after each: a bench stopped half-way keeps what it had
    record.show(tables({"cases": results}))


def tables(result: dict) -> list[record.Table]:
    rows = []
    for name, case in result["cases"].items():
        if "failed" in case:
            rows.append([name, case["failed"], "-", "-", "-"])
            continue
        rows.append([name, f"{case['equilibrium_error_max_percent']:.2f} (at {case['worst_at_um']} µm)",
                     f"{case['damping_error_max_percent']:.1f}", case["truth_inside_interval"],
                     f"{case['rig_time_s']:.1f}"])
    return [record.Table("Each truth identified over the rig protocol (the emulator's watchdog 0.2 s):",
                         ["truth", "equilibrium heights 50-200 µm: largest error [%]",
                          "damping factor: largest error [%]", "truth inside the interval", "rig time [s]"], rows)]

if __name__ == "__main__":
    main(sys.argv[1:])
