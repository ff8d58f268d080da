"""What a late DRIVE costs the levitated object: the physics behind the rig's 20 ms watchdog (docs/hil.md).

    python bench/watchdog_hold.py

The loop of the identification's moves and of fig7 (the paper's gain schedule realisable at 2 kHz, eq. 13 with the
rig-like excess damping, the transducer's amplitude lag) steps 100 -> 140 um and 140 -> 100 um. At a moment of the
transient the host stops: the rig holds the last drive (what its firmware does until the watchdog trips), then the
host is back and the loop goes on (its law takes every sample that came meanwhile). For each hold length and each
start of the hold (every 5 ms over the first 100 ms of the step: the worst is reported), the overshoot beyond the
new level (percent of the step) and the lowest clearance, against the uninterrupted run's. A dead host instead: the
watchdog trips after 20 ms and ramps the drive to 0 V over 50 ms; the object sinks on its squeeze film (the time to
20 um and the fastest fall are reported).
Writes bench/results/watchdog-hold.json.
"""

from __future__ import annotations

import json
import math

import numpy as np

import record
from nfal.models.calibration import paper_calibration
from nfal.models.control_law import DiscreteControlLaw
from nfal.models.fixed_step_plant import FixedStepPlant
from nfal.models.identification import AMPLITUDE_TIME_CONSTANT_S
from nfal.models.pid_design import design_schedule
from nfal.models.plant import ExcessDamping, PlantState, SimplifiedPlant
from nfal.models.rig import RigParameters
from nfal.models.stability import realizable_schedule

PERIOD_S = 5e-4
HOLDS_MS = (1, 2, 5, 10, 20, 50, 100)
STEPS_M = ((100e-6, 140e-6), (140e-6, 100e-6), (60e-6, 100e-6))
RAMP_S = 0.05


def run(plant: FixedStepPlant, design: SimplifiedPlant, law: DiscreteControlLaw, before: float, after: float,
        hold_start: int | None, hold_samples: int, ramp: bool = False, samples: int = 1200) -> np.ndarray:
    """Heights [m] of the step (at sample 100), the drive held from ``hold_start`` for ``hold_samples`` samples."""
    state = PlantState(before)
    controller = law.initial_state(before, float(design.equilibrium_excitation(before)))
    amplitude = command = float(design.equilibrium_excitation(before))
    decay = math.exp(-PERIOD_S / AMPLITUDE_TIME_CONSTANT_S)
    heights = np.empty(samples)
    for k in range(samples):
        heights[k] = state.height
        if hold_start is not None and k == hold_start:  # the last drive before the host stopped: the rig holds it
            held_command = command
        held = hold_start is not None and hold_start <= k < hold_start + hold_samples
        if hold_start is not None and ramp and k >= hold_start + hold_samples:  # the watchdog's ramp, then 0
            fraction = min(1.0, (k - hold_start - hold_samples) * PERIOD_S / RAMP_S)
            command = held_command * (1 - fraction)
        elif not held:
            command, controller = law.step(controller, after if k >= 100 else before, state.height)
        amplitude = command + (amplitude - command) * decay
        state = plant.advance(state, amplitude, PERIOD_S)
        if state.resting:
            heights[k + 1:] = state.height
            return heights
    return heights


def main() -> None:
    rig = RigParameters()
    design = SimplifiedPlant(rig, paper_calibration())
    truth = FixedStepPlant(SimplifiedPlant(rig, paper_calibration(), excess_damping=ExcessDamping.rig_like()),
                           near_surface="fast")
    law = DiscreteControlLaw(realizable_schedule(design_schedule()), max_excitation_m=10e-6,
                             reference_range_m=(50e-6, 200e-6))
    rows = []

    def judge(heights: np.ndarray, before: float, after: float) -> tuple[float, float]:
        beyond = np.max(heights[100:] - after) if after > before else np.max(after - heights[100:])
        return 100 * max(0.0, float(beyond)) / abs(after - before), float(np.min(heights)) * 1e6

    for before, after in STEPS_M:
        nominal = judge(run(truth, design, law, before, after, None, 0), before, after)
        for hold_ms in (0, *HOLDS_MS):
            samples = round(hold_ms * 1e-3 / PERIOD_S)
            judged = [judge(run(truth, design, law, before, after, start, samples), before, after)
                      for start in range(100, 300, 10)] if hold_ms else [nominal]
            rows.append({"step_um": [round(before * 1e6), round(after * 1e6)], "hold_ms": hold_ms,
                         "worst_overshoot_percent": round(max(j[0] for j in judged), 1),
                         "lowest_clearance_um": round(min(j[1] for j in judged), 1)})
            print(json.dumps(rows[-1]), flush=True)
    landing = run(truth, design, law, 100e-6, 100e-6, 200, 40, ramp=True, samples=40000)
    below = np.flatnonzero(landing < 20e-6)
    dead = {"time_to_20_um_s": round(float(below[0] - 240) * PERIOD_S, 3) if below.size else None,
            "fall_speed_max_mm_s": round(float(np.max(-np.diff(landing)) / PERIOD_S) * 1e3, 3)}
    print(json.dumps({"dead_host_at_100_um": dead}), flush=True)
    print(record.save("watchdog-hold", {"rows": rows, "dead_host_at_100_um": dead}), flush=True)


def tables(result: dict) -> list[record.Table]:
    return [record.Table("The worst over the hold's start (every 5 ms over the step's first 100 ms):",
                         ["step [µm]", "hold [ms]", "worst overshoot [% of the step]", "lowest clearance [µm]"],
                         [[" -> ".join(map(str, row["step_um"])), row["hold_ms"], row["worst_overshoot_percent"],
                           row["lowest_clearance_um"]] for row in result["rows"]])]


def findings(result: dict) -> list[str]:
    dead = result["dead_host_at_100_um"]
    return [f"A dead host at 100 µm (the watchdog trips after 20 ms, the drive ramps to 0 V over 50 ms): the object "
            f"reaches 20 µm after {dead['time_to_20_um_s']:g} s, falling at most {dead['fall_speed_max_mm_s']:g} "
            "mm/s."]

if __name__ == "__main__":
    main()
