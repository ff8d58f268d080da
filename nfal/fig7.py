"""What the Fig. 7 loop's results mean to a person: the response plot's panels and the step metrics.

The orchestrator is generic; this module knows the loop's element and variable names (docs/cosimulation.md),
in both variants: simulated (fig7_slow, fig7_reynolds) and hardware in the loop (fig7_hil, where the
``proxy`` element stands for the rig and only the measured height is known).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from nfal.models.closed_loop import ClosedLoopRun, Staircase
from nfal.models.step_metrics import step_metrics, total_iae

REFERENCE = "Controller.reference"
PROXY = "proxy"


@dataclasses.dataclass(frozen=True)
class LoopColumns:
    """Where a loop variant keeps the quantities the metrics and the plot need."""

    height: str       #: the height the metrics judge (the true one where known)
    measured: str
    excitation: str
    frequency: str
    extra_panels: tuple = ()


SIMULATED = LoopColumns("Plant.height", "SensorChain.measured_height", "ResonanceTracker.excitation_amplitude",
                        "ResonanceTracker.drive_frequency")
HARDWARE = LoopColumns(f"{PROXY}.measured_height", f"{PROXY}.measured_height", "Controller.excitation_command",
                       f"{PROXY}.drive_frequency",
                       extra_panels=(((("Controller.drive_voltage", f"{PROXY}.applied_voltage"), 1.0, "drive [V]")),
                                     (((f"{PROXY}.measurement_age",), 1e3, "sample age [ms]"))))


def loop_columns(element_names) -> LoopColumns:
    """HARDWARE when the structure has the ``proxy`` element, else SIMULATED."""
    return HARDWARE if PROXY in set(element_names) else SIMULATED


def response_panels(columns: LoopColumns = SIMULATED) -> list:
    """Height (reference, true, measured) in um; excitation in um; the drive frequency's change in Hz (and, with
    hardware, the commanded and applied voltage and the age of the sample used)."""
    from nfal.orchestration import PlotPanel

    heights = (REFERENCE, columns.measured) + ((columns.height,) if columns.height != columns.measured else ())
    excitation = tuple(dict.fromkeys(("Controller.excitation_command", columns.excitation)))
    return [PlotPanel(heights, 1e6, "height [um]"), PlotPanel(excitation, 1e6, "|a| [um]"),
            PlotPanel((columns.frequency,), 1.0, "drive frequency change [Hz]", from_start=True),
            *(PlotPanel(*panel) for panel in columns.extra_panels)]


def loop_run(table, name: str = "fmu loop", columns: LoopColumns = SIMULATED) -> ClosedLoopRun:
    """The Fig. 7 columns of a result table as a :class:`ClosedLoopRun` (for :func:`step_metrics`)."""
    return ClosedLoopRun(name, np.asarray(table.time), np.asarray(table[REFERENCE]), np.asarray(table[columns.height]),
                         np.asarray(table[columns.measured]), np.asarray(table[columns.excitation]))


def loop_metrics(table, reference: Staircase, columns: LoopColumns = SIMULATED) -> dict:
    """Total IAE and the per-step metrics of Figs. 9-10 (``nfal compare``'s definitions), SI."""
    run = loop_run(table, columns=columns)
    return {"iae": total_iae(run), "steps": [m.to_dict() for m in step_metrics(run, reference)]}


#: The proxy's link-health outputs summarised after a hardware-in-the-loop run (their last or worst value).
LINK_TOTALS = ("frames_dropped", "frames_lost", "rig_faults", "reconnects")


def link_summary(table) -> dict:
    """The link's health over a hardware-in-the-loop run: final counters, worst sample age and misses."""
    summary = {name: int(np.asarray(table[f"{PROXY}.{name}"])[-1]) for name in LINK_TOTALS}
    age = np.asarray(table[f"{PROXY}.measurement_age"])
    summary.update(samples_missed_max=int(np.max(table[f"{PROXY}.samples_missed"])),
                   measurement_age_max_s=float(np.max(age)), measurement_age_mean_s=float(np.mean(age)),
                   stale_steps=int(np.count_nonzero(~np.asarray(table[f"{PROXY}.fresh"], dtype=bool))))
    return summary
