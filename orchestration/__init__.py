"""Runs SSP system structures of anyone's FMI 2.0 and FMI 3.0 co-simulation FMUs over fmpy (never imports nfal.fmus).

Modules, one job each: :mod:`.ssp` reads SSP 1.0 into data classes; :mod:`.resolve` checks them
against the FMUs and flattens them; :mod:`.schedule` orders the exchange at a communication point;
:mod:`.master` runs the FMUs (algorithms ``causal`` and ``jacobi``); :mod:`.signals` makes reference
inputs; :mod:`.results` writes and reads the CSV, ``summary.json`` and the plot; :mod:`.pacing`
releases steps on the wall clock; :mod:`.checks` turns what a caller's checks find into a run's status;
:mod:`.run` ties them together in :func:`run_structure`.
:mod:`.ssp_archive` packs SSP archives and :mod:`.ssp_schema` checks them against the SSP 1.0
schemas; :mod:`.libcosim` runs an archive in OSP libcosim; :mod:`.sweep_spec` and :mod:`.sweep` run
many runs on Dask.
"""

from nfal.errors import (AlgebraicLoopError, CausalityError, FmuCallError, MissingFmuError, OrchestrationError,
                         RunCheckError, SignalError, SimulationError, StructureError, TypeMismatchError,
                         UnitMismatchError, UnknownConnectorError, UnknownElementError, UnsupportedFeatureError)

from .checks import Finding
from .master import ALGORITHMS, Master
from .resolve import ResolvedSystem, resolve
from .results import PlotPanel, ResultTable, read_results
from .run import RunResult, run_structure
from .signals import PiecewiseConstant, csv_signal, signal_from_spec, staircase, step
from .ssp import SystemStructure, read_ssp

__all__ = [
    "ALGORITHMS", "AlgebraicLoopError", "CausalityError", "Finding", "FmuCallError", "Master", "MissingFmuError",
    "OrchestrationError", "PiecewiseConstant", "PlotPanel", "ResolvedSystem", "ResultTable", "RunCheckError",
    "RunResult", "SignalError", "SimulationError", "StructureError", "SystemStructure", "TypeMismatchError",
    "UnitMismatchError", "UnknownConnectorError", "UnknownElementError", "UnsupportedFeatureError", "csv_signal",
    "read_results", "read_ssp", "resolve", "run_structure", "signal_from_spec", "staircase", "step",
]
