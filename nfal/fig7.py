"""What the Fig. 7 loop's results mean to a person: the response plot's panels and the step metrics.

The orchestrator is generic; this module knows the loop's element and variable names (docs/cosimulation.md).
"""

from __future__ import annotations

import numpy as np

from nfal.models.closed_loop import ClosedLoopRun, Staircase
from nfal.models.step_metrics import step_metrics, total_iae

REFERENCE, HEIGHT, MEASURED = "Controller.reference", "Plant.height", "SensorChain.measured_height"
EXCITATION = "ResonanceTracker.excitation_amplitude"


def response_panels() -> list:
    """Height (reference, true, measured) in um; excitation in um; drive frequency in Hz."""
    from nfal.orchestration import PlotPanel

    return [PlotPanel((REFERENCE, MEASURED, HEIGHT), 1e6, "height [um]"),
            PlotPanel(("Controller.excitation_command", EXCITATION), 1e6, "|a| [um]"),
            PlotPanel(("ResonanceTracker.drive_frequency",), 1.0, "drive frequency [Hz]")]


def loop_run(table, name: str = "fmu loop") -> ClosedLoopRun:
    """The Fig. 7 columns of a result table as a :class:`ClosedLoopRun` (for :func:`step_metrics`)."""
    return ClosedLoopRun(name, np.asarray(table.time), np.asarray(table[REFERENCE]), np.asarray(table[HEIGHT]),
                         np.asarray(table[MEASURED]), np.asarray(table[EXCITATION]))


def loop_metrics(table, reference: Staircase) -> dict:
    """Total IAE and the per-step metrics of Figs. 9-10 (``nfal compare``'s definitions), SI."""
    run = loop_run(table)
    return {"iae": total_iae(run), "steps": [m.to_dict() for m in step_metrics(run, reference)]}
