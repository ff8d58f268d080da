"""nfal's sweep kinds: the Fig. 7 loop over an SSP archive, K(sigma) by perturbation, and Table 1 cases.

Each kind is one :class:`~nfal.orchestration.sweep_spec.SweepKind` in :data:`KINDS` (its ``[run]``
settings, what a grid may set, its task and metric columns); a new kind is one more entry. The values that
are paths (:func:`file_in`: ``shape`` and ``calibration``, as settings or as any FMU's parameters) are read
from the spec's folder and shipped to the workers, as the structure is. The engine
(:mod:`nfal.orchestration.sweep`) runs any of them on Dask; :func:`load_spec` and :func:`parse_spec`
read a spec against this registry.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import tempfile
from pathlib import Path

import numpy as np

from nfal.errors import InvalidParameterError, SweepSpecError
from nfal.apps.fig7 import REFERENCE, SIMULATED, loop_checks, loop_metrics, matched_design, reference_staircase
from nfal.fmus.rig_contract import CALIBRATION_CHOICES
from nfal.models.calibration import perturbation_calibration
from nfal.models.plausibility import require_clearances
from nfal.models.reference import Staircase
from nfal.models.excitation import parse_shape
from nfal.models.table1 import TABLE1, run_case
from nfal.orchestration import sweep_spec
from nfal.orchestration.run import MAX_STEPS, run_structure
from nfal.orchestration.sweep_spec import RunSpec, SweepKind, check_number, sweepable

SSP_METRICS = ("iae_m_s", "rise_time_s", "overshoot_percent", "settling_time_s", "steady_state_error_m",
               "noise_rms_m")
TABLE1_METRICS = ("delta_simplified", "delta_full", "error_percent")


@dataclasses.dataclass(frozen=True)
class Ramp:
    """``initial`` until ``start_s``, then linear to ``final`` over ``duration_s`` [s], then held."""

    initial: float
    final: float
    start_s: float
    duration_s: float

    def __call__(self, time_s: float) -> float:
        if time_s <= self.start_s:
            return self.initial
        fraction = min(1.0, (time_s - self.start_s) / self.duration_s) if self.duration_s > 0 else 1.0
        return self.initial + fraction * (self.final - self.initial)


def _staircase(reference, structure: str):
    """The run's reference: the structure's default staircase (as ``nfal run`` takes it), none, or the spec's."""
    if reference == "staircase":
        return reference_staircase("staircase", Path(structure).stem)
    if reference == "none":
        return None
    return Staircase(tuple(reference["levels_m"]), **{k: reference[k] for k in ("hold_s", "lead_s") if k in reference})


def ssp_run_time(settings: dict) -> float | None:
    """The time an SSP run simulates [s]: ``stop_time``, else its staircase's duration (None: the structure's own)."""
    if settings["stop_time"] is not None:
        return float(settings["stop_time"])
    staircase = _staircase(settings["reference"], settings["structure"])
    return staircase.duration_s if staircase is not None else None


def loop_summary(table, staircase) -> dict:
    """The sweep's metrics of a Fig. 7 run: IAE, the worst step's rise/settling time and overshoot,
    the final hold's steady-state error |mean(height - reference)| over its last quarter, mean noise."""
    metrics = loop_metrics(table, staircase)
    steps = metrics["steps"]

    def worst(key):
        values = [s[key] for s in steps]
        return math.nan if not values or any(v is None for v in values) else float(max(values))

    time_s = np.asarray(table.time)
    tail_start = time_s[-1] - 0.25 * (time_s[-1] - float(staircase.step_times_s[-1]))
    tail = time_s >= tail_start
    error = np.asarray(table[SIMULATED.height])[tail] - np.asarray(table[REFERENCE])[tail]
    return {"iae_m_s": float(metrics["iae"]), "rise_time_s": worst("rise_time_s"),
            "overshoot_percent": worst("overshoot_percent"), "settling_time_s": worst("settling_time_s"),
            "steady_state_error_m": float(abs(np.mean(error))),
            "noise_rms_m": float(np.mean([s["noise_rms_m"] for s in steps]))}


def ssp_task(run: RunSpec, path: Path) -> dict:
    """One SSP run: the archive (unpacked in the worker cache) with the run's overrides; the loop metrics and the
    checks' warnings (a failed check raises, as ``nfal run`` fails: a failed row with the reason)."""
    settings = run.settings
    parameters = dict(settings["parameters"])
    inputs: dict = {k: float(v) for k, v in settings["inputs"].items()}
    for name, value in run.parameters.items():
        if name.startswith("inputs."):
            target = name[len("inputs."):]
            ramp = settings["ramps"].get(target)
            inputs[target] = (Ramp(float(ramp.get("initial", 0.0)), float(value), float(ramp.get("start_s", 0.0)),
                                   float(ramp["duration_s"])) if ramp is not None else float(value))
        else:
            parameters[name] = value
    parameters = matched_design(parameters)  # a swept Plant.shape: the Controller designed on that film, as nfal run
    staircase = _staircase(settings["reference"], settings["structure"])
    if staircase is not None:
        inputs.setdefault(settings["reference_input"], staircase)
    stop_time = ssp_run_time(settings)
    completed = staircase.completed_by(stop_time) if staircase is not None and stop_time else None
    with tempfile.TemporaryDirectory(prefix="nfal-sweep-run-") as out:
        result = run_structure(path, stop_time=stop_time, step_size=settings["step_size"], inputs=inputs,
                               parameters=parameters, algorithm=settings["algorithm"], out_dir=out, plot=False,
                               progress=False, checks=lambda table: loop_checks(table, completed))
        warnings = {"warnings": "; ".join(result.summary["warnings"])}
        return warnings if completed is None else {**loop_summary(result.table(), completed), **warnings}


def calibration_task(run: RunSpec, _structure: None = None) -> dict:
    """K(sigma) by the perturbation route for the run's shape: K at the spec's sigma, K's least and greatest
    value on the grid, and the first sigma where K changes sign (NaN if it does not)."""
    s = {**run.settings, **run.parameters}
    calibration = perturbation_calibration(parse_shape(str(s["shape"])), tuple(s["sigma_range"]),
                                           points=int(s["points"]), nodes=int(s["nodes"]))
    values = np.asarray(calibration(np.asarray(run.settings["sigma"], dtype=float)), dtype=float)
    grid = np.geomspace(*(float(v) for v in s["sigma_range"]), int(s["points"]))
    on_grid = np.asarray(calibration(grid), dtype=float)
    out = {f"K_at_sigma_{sigma:g}": float(v) for sigma, v in zip(run.settings["sigma"], values)}
    crossings = np.flatnonzero(np.diff(np.sign(on_grid)) != 0)
    if crossings.size:
        i = int(crossings[0])
        zero = float(grid[i] - on_grid[i] * (grid[i + 1] - grid[i]) / (on_grid[i + 1] - on_grid[i]))
    else:
        zero = math.nan
    out.update({"K_min": float(on_grid.min()), "K_max": float(on_grid.max()), "sigma_K_zero": zero})
    return out


def table1_task(run: RunSpec, _structure: None = None) -> dict:
    """One Table-1 case (simplified model against the full Reynolds model), with the run's overrides."""
    s = {**run.settings, **run.parameters}
    cases = {c.name: c for c in TABLE1}
    if s["case"] not in cases:
        raise InvalidParameterError("case", s["case"], f"one of {', '.join(cases)}")
    changes = {k: float(s[k]) for k in ("mass", "frequency", "excitation") if s.get(k) is not None}
    case = dataclasses.replace(cases[s["case"]], **changes)
    result = run_case(case, shape=parse_shape(str(s["shape"])), nodes=int(s["nodes"]),
                      steps_per_period=int(s["steps_per_period"]))
    return {"delta_simplified": float(result.delta_simplified), "delta_full": float(result.delta_full),
            "error_percent": float(result.error_percent)}


# ---------------------------------------------------------------------------------------------- paths

def _shape_file(shape: str) -> str | None:
    """The CSV path a shape names, None for one parse_shape knows by name (models/excitation.py)."""
    return None if shape in ("piston", "paper") or shape.startswith("plate:") else shape


def file_in(name: str, value: object) -> tuple[str, str] | None:
    """The file a ``shape`` or ``calibration`` value names (a ``[run]`` setting, or an FMU parameter
    ``Element.shape``/``Element.calibration``): ``(prefix, path)`` with ``value == prefix + path``, or None for the
    values they take by name (piston, paper, plate:N; paper, perturbation, perturbation:SHAPE)."""
    if not isinstance(value, str):
        return None
    field = name.rpartition(".")[2]
    if field == "shape":
        path, prefix = _shape_file(value), ""
    elif field == "calibration" and value not in CALIBRATION_CHOICES:
        prefix = "perturbation:" if value.startswith("perturbation:") else ""
        path = _shape_file(value[len(prefix):]) if prefix else value
    else:
        return None
    return None if path is None else (prefix, path)


# ---------------------------------------------------------------------------------------------- checks

def _check_ssp_settings(settings: dict, swept: list[str]) -> None:
    check_number(settings, "stop_time", optional=True)
    check_number(settings, "step_size")
    for key in ("parameters", "inputs", "ramps"):
        if not isinstance(settings[key], dict):
            raise SweepSpecError(f"[run] {key} must be a table")
    for key, value in settings["inputs"].items():
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
            raise SweepSpecError(f"[run.inputs] {key} = {value!r}; must be a finite number (a constant)")
    for key, ramp in settings["ramps"].items():
        if not isinstance(ramp, dict) or set(ramp) - {"start_s", "duration_s", "initial"} or "duration_s" not in ramp:
            raise SweepSpecError(f"[run.ramps] {key} = {ramp!r}; must be {{start_s, duration_s[, initial]}}")
    for name in settings["inputs"]:
        if f"inputs.{name}" in swept:
            raise SweepSpecError(f"[run.inputs] {name!r} has no effect: \"inputs.{name}\" is swept (each run sets it)")
    for name in settings["ramps"]:
        if f"inputs.{name}" not in swept:
            raise SweepSpecError(f"[run.ramps] {name!r} has no effect without \"inputs.{name}\" swept (a ramp ends at "
                                 "the swept value)")
    reference = settings["reference"]
    if not (reference in ("staircase", "none") or (isinstance(reference, dict) and "levels_m" in reference
                                                   and set(reference) <= {"levels_m", "hold_s", "lead_s"})):
        raise SweepSpecError(f"[run] reference = {reference!r}; must be \"staircase\", \"none\" or "
                             "{levels_m = [...], hold_s = ..., lead_s = ...}")
    if isinstance(reference, dict):  # levels in um given as m: every run would fail at its first step
        try:
            require_clearances("[run] reference.levels_m", reference["levels_m"])
        except InvalidParameterError as exc:
            raise SweepSpecError(str(exc)) from None
    run_time = ssp_run_time(settings)
    if run_time is not None and run_time / settings["step_size"] > MAX_STEPS:  # every run would be refused at its start
        raise SweepSpecError(f"[run] a run of {run_time:g} s at step_size = {settings['step_size']:g} s is "
                             f"{run_time / settings['step_size']:,.0f} steps; at most {MAX_STEPS:,} "
                             "(a shorter stop_time or a longer step)")


def _check_ssp_name(name: str, table: str) -> None:
    if name.startswith("inputs."):
        if len(name) > len("inputs."):
            return
    elif "." in name.strip(".") and not name.startswith("."):
        return
    raise SweepSpecError(f"[{table}] {name!r}: an SSP run sweeps \"Element.variable\" parameters or "
                         "\"inputs.NAME\" (a constant, or a ramp's final value with [run.ramps])")


def _check_calibration_settings(settings: dict, _swept: list[str]) -> None:
    sigma = settings["sigma"]
    if not isinstance(sigma, list) or not sigma or not all(
            isinstance(s, (int, float)) and not isinstance(s, bool) and s > 0 for s in sigma):
        raise SweepSpecError(f"[run] sigma = {sigma!r}; must be a list of positive squeeze numbers")


def _calibration_metrics(settings: dict) -> tuple[str, ...]:
    return tuple(f"K_at_sigma_{s:g}" for s in settings["sigma"]) + ("K_min", "K_max", "sigma_K_zero")


#: The registry: ``[run] kind`` -> what its runs are.
KINDS = {kind.name: kind for kind in (
    SweepKind("ssp", {"structure": "fig7_slow", "stop_time": None, "step_size": 5e-4, "algorithm": "causal",
                      "reference": "staircase", "reference_input": REFERENCE, "parameters": {}, "inputs": {},
                      "ramps": {}},
              ssp_task, lambda settings: SSP_METRICS, _check_ssp_name, _check_ssp_settings, needs_archive=True,
              run_time=ssp_run_time, file_in=file_in),
    SweepKind("calibration", {"shape": "paper", "sigma": [10.0, 100.0, 1000.0], "sigma_range": [1.0, 1e5],
                              "points": 200, "nodes": 401},
              calibration_task, _calibration_metrics, sweepable("shape", "points", "nodes", "sigma_range"),
              _check_calibration_settings, file_in=file_in),
    SweepKind("table1", {"case": "a", "shape": "paper", "nodes": 101, "steps_per_period": 256, "mass": None,
                         "frequency": None, "excitation": None},
              table1_task, lambda settings: TABLE1_METRICS,
              sweepable("case", "shape", "nodes", "steps_per_period", "mass", "frequency", "excitation"),
              file_in=file_in),
)}

#: A spec against :data:`KINDS`: ``load_spec(path)``, ``parse_spec(data, base_dir=..., source=...)``.
load_spec = functools.partial(sweep_spec.load_spec, kinds=KINDS)
parse_spec = functools.partial(sweep_spec.parse_spec, kinds=KINDS)
