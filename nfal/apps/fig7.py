"""What the Fig. 7 loop's results mean to a person: the response plot's panels, the step metrics, and the checks
that make a run's status (the object lifted off, the reference's levels reached).

The orchestrator is generic; this module knows the loop's element and variable names (docs/cosimulation.md),
in both variants: simulated (fig7_slow, fig7_reynolds) and hardware in the loop (fig7_hil, where the
``proxy`` element stands for the rig and only the measured height is known).
"""

from __future__ import annotations

import dataclasses
import importlib.resources
from pathlib import Path

import numpy as np
from lxml import etree

from nfal.errors import InvalidParameterError
from nfal.apps.fig7_names import (  # noqa: F401
    CONTROLLER_CALIBRATION,
    EXCITATION_COMMAND,
    GENERATED_REFERENCE,
    HARDWARE,
    PLANT_SHAPE,
    PROXY,
    REFERENCE,
    REFERENCE_GENERATOR,
    SATURATED_TIME,
    SIMULATED,
    LoopColumns,
)
from nfal.models.calibration import paper_calibration
from nfal.models.closed_loop import ClosedLoopRun, simulate_closed_loop
from nfal.models.reference import Staircase
from nfal.models.control_law import SATURATION_WARNING_S, DiscreteControlLaw
from nfal.models.measurement_noise import coloured_noise
from nfal.models.pid_design import DesignSpec, design_schedule
from nfal.models.plausibility import require_clearances
from nfal.models.plant import SimplifiedPlant
from nfal.models.reference import StepSequence
from nfal.models.rig import RigParameters
from nfal.models.step_metrics import REACHED_BAND, level_reach, step_metrics, total_iae
from nfal.models.table2 import REFERENCE_ZERO_RATIO
from nfal.orchestration import Finding, PiecewiseConstant, PlotPanel
from nfal.orchestration.signals import steps_of
from nfal.orchestration.ssp import read_parameter_set

#: The staircase of the Reynolds loop: the part of Figs. 9-10's range the film of the Fig. 3 stand-in form
#: holds with |a| <= 10 um (up to ~107 um; its K is negative above 118 um): the paper's 60 -> 100 and
#: 100 -> 60 steps (the first and last of Figs. 9-10), three times over the paper's 3.7 s
#: (docs/cosimulation.md, "A consistent Reynolds loop").
REYNOLDS_LEVELS_M = (60e-6, 100e-6, 60e-6, 100e-6, 60e-6, 100e-6, 60e-6)
#: Default staircases by structure name (others: the paper's, Staircase()).
DEFAULT_STAIRCASES = {"fig7_reynolds": Staircase(REYNOLDS_LEVELS_M)}


def reference_staircase(spec: str, structure: str, lead_s: float | None = None) -> Staircase | None:
    """The staircase ``--reference`` names: 'staircase' (the structure's default, see ``DEFAULT_STAIRCASES``),
    'staircase:L1,L2,...[:HOLD[:LEAD]]' [m, s], or None for anything else (a CSV). ``lead_s`` replaces
    the default's first hold (hardware)."""
    kind, _, rest = spec.partition(":")
    if kind != "staircase":
        return None
    if not rest:
        default = DEFAULT_STAIRCASES.get(structure, Staircase())
        return default if lead_s is None else dataclasses.replace(default, lead_s=lead_s)
    parts = rest.split(":")
    try:
        levels, timing = tuple(float(v) for v in parts[0].split(",")), tuple(float(p) for p in parts[1:3])
    except ValueError:
        raise InvalidParameterError("--reference", spec, "staircase, staircase:L1,L2,...[:HOLD[:LEAD]] (m, s) "
                                    "or a CSV file") from None
    require_clearances("--reference levels", levels)  # 60 for 60 um fails here, not at the run's first step
    return Staircase(levels, *timing)


@dataclasses.dataclass(frozen=True)
class GeneratedReference:
    """What feeds ``Controller.reference`` in a structure: ``source`` (``Element.output``) and, when it is a
    ReferenceGenerator FMU, the reference its parameters make (a Staircase or a StepSequence; None otherwise)."""

    source: str
    reference: object | None


def generated_reference(system, target: str = REFERENCE) -> GeneratedReference | None:
    """The output connected to ``target`` (``Controller.reference``, where the structure has it) in the resolved
    ``system`` (:func:`nfal.orchestration.resolve`), or None: the structure leaves the reference to the host.

    The ReferenceGenerator's reference is worked out from its parameters as the FMU works it out
    (:func:`nfal.fmus.reference_generator.reference_of`): the SSD's bindings and ``--param`` overrides, the
    FMU's defaults otherwise. A ``table`` that names a file inside the FMU, or another FMU, leaves it unknown.
    """
    # on use: the FMU's slave module (pythonfmu) loads only when a structure is read
    from nfal.fmus.reference_generator import PARAMETERS, reference_of

    link = next((candidate for candidate in system.links if candidate.target.path == target), None)
    if link is None:
        return None
    element = next(e for e in system.elements if e.name == link.source.element)
    if element.model_description.coSimulation.modelIdentifier != REFERENCE_GENERATOR:
        return GeneratedReference(link.source.path, None)
    parameters = {name: value for name, value in element.start_values.items() if name in PARAMETERS}
    table = str(parameters.get("table", "")).strip()
    if table.lower().endswith(".csv") and "," not in table:
        return GeneratedReference(link.source.path, None)  # a file inside the FMU: the FMU reads it
    return GeneratedReference(link.source.path, reference_of(parameters))


def matched_design(parameters: dict) -> dict:
    """``parameters`` with Controller.calibration = 'perturbation:SHAPE' added when Plant.shape = SHAPE is
    given and Controller.calibration is not: the Reynolds loop's controller is designed on the film it
    controls (docs/cosimulation.md)."""
    if PLANT_SHAPE in parameters and CONTROLLER_CALIBRATION not in parameters:
        return {**parameters, CONTROLLER_CALIBRATION: f"perturbation:{parameters[PLANT_SHAPE]}"}
    return parameters


#: The staircase's first hold against hardware [s]: the rig starts with the object at rest, and lift-off to
#: the first level takes about half a second (the simulated loops start at 60 um: 0.1 s, as in Figs. 9-10).
HARDWARE_LEAD_S = 1.0
#: The Reynolds loop's design parameters that are its control law, not its film (ssp/reynolds_design.ssv binds all).
REYNOLDS_LAW_PARAMETERS = ("placement", "closed_loop_cutoff", "feedforward", "reference_filter_time")


def reynolds_law() -> dict:
    """The Controller parameters of the Reynolds loop's law (placement, cut-off, feedforward path), read from
    ssp/reynolds_design.ssv: with them fig7_slow runs the same law on its own plant."""
    path = Path(str(importlib.resources.files("nfal.ssp") / "reynolds_design.ssv"))
    values = read_parameter_set(etree.parse(str(path)).getroot(), source=path).values
    return {f"Controller.{v.name}": v.value for v in values if v.name in REYNOLDS_LAW_PARAMETERS}


#: The fig7_slow parameters that make the FMU loop the pure-Python loop of ``nfal compare``
#: (:func:`pure_python_loop`): the blocks it leaves out made transparent.
PURE_LOOP_PARAMETERS = {"ResonanceTracker.transducer_dynamics": False, "SensorChain.analog_cutoff": 0.0,
                        "SensorChain.resolution": 0.0, "Controller.actuator_lag": 0.0,
                        "Controller.reference_filter_time": 0.0}


def pure_python_loop(reference: Staircase, seed: int = 0) -> ClosedLoopRun:
    """The pure-Python loop (the default gain schedule at 2 kHz, eq. 13 with eq. 17, coloured noise of ``seed``)
    that fig7_slow with :data:`PURE_LOOP_PARAMETERS` reproduces to rounding."""
    rig, calibration = RigParameters(), paper_calibration()
    schedule = design_schedule(None, rig, calibration,
                               DesignSpec(sample_rate_hz=2000.0, reference_zero=REFERENCE_ZERO_RATIO))
    law = DiscreteControlLaw(schedule, sample_rate_hz=2000.0, max_excitation_m=10e-6,
                             reference_zero_ratio=REFERENCE_ZERO_RATIO)
    noise = coloured_noise(reference.samples(2000.0), seed=seed)
    return simulate_closed_loop(law, SimplifiedPlant(rig, calibration), reference, noise)


def loop_columns(element_names) -> LoopColumns:
    """HARDWARE when the structure has the ``proxy`` element, else SIMULATED, located in the structure's hierarchical
    ``element_names`` (:meth:`LoopColumns.located`)."""
    proxy = any(name.rpartition(".")[2] == PROXY for name in element_names)
    return (HARDWARE if proxy else SIMULATED).located(element_names)


def response_panels(columns: LoopColumns = SIMULATED) -> list:
    """Height (reference, true, measured) in um; excitation in um; the drive frequency's change in Hz (and, with
    hardware, the commanded and applied voltage and the age of the sample used)."""
    heights = (columns.reference, columns.measured) + ((columns.height,) if columns.height != columns.measured else ())
    excitation = tuple(dict.fromkeys((columns.command, columns.excitation)))
    return [PlotPanel(heights, 1e6, "height [um]"), PlotPanel(excitation, 1e6, "|a| [um]"),
            PlotPanel((columns.frequency,), 1.0, "drive frequency change [Hz]", from_start=True),
            *(PlotPanel(*panel) for panel in columns.extra_panels)]


def loop_run(table, name: str = "fmu loop", columns: LoopColumns = SIMULATED) -> ClosedLoopRun:
    """The Fig. 7 columns of a result table as a :class:`ClosedLoopRun` (for :func:`step_metrics`)."""
    return ClosedLoopRun(name, np.asarray(table.time), np.asarray(table[columns.reference]),
                         np.asarray(table[columns.height]), np.asarray(table[columns.measured]),
                         np.asarray(table[columns.excitation]))


def step_reference(reference, start_s: float, stop_s: float) -> tuple[object | None, str | None]:
    """The steps of a run's reference for the step metrics and the checks, or None and why there are none: a
    staircase's steps completed by ``stop_s``, or the steps of a piecewise-constant reference (a CSV, the
    ReferenceGenerator's times or table; :func:`~nfal.orchestration.signals.steps_of`)."""
    if isinstance(reference, Staircase) and start_s > reference.step_times_s[0]:  # a run that starts mid-staircase
        reference = PiecewiseConstant([min(0.0, start_s), *reference.step_times_s], reference.levels_m)
    if isinstance(reference, Staircase):
        completed = reference.completed_by(stop_s)
        why = None if completed is not None else f"no step of the staircase completes its hold by {stop_s:g} s"
        return completed, why
    if isinstance(reference, StepSequence):
        reference = PiecewiseConstant(reference.times_s, reference.levels_m)
    if isinstance(reference, PiecewiseConstant):
        return steps_of(reference, start_s, stop_s)
    return None, "the reference's levels are not known before the run (a table inside the ReferenceGenerator FMU)"


def loop_metrics(table, reference, columns: LoopColumns = SIMULATED, *, no_steps: str | None = None) -> dict:
    """Total IAE and the per-step metrics of Figs. 9-10 (``nfal compare``'s definitions) of a step reference
    (a staircase, or :func:`step_reference`'s steps), SI, the drive's long saturations
    (:func:`saturation_episodes`), and the first level apart (:func:`first_level`). With ``reference`` None:
    the IAE, the saturations, and ``no_steps``, why there is no step table."""
    run = loop_run(table, columns=columns)
    saturation = saturation_episodes(table, columns=columns)
    if reference is None:
        return {"iae": total_iae(run), "steps": None, "no_steps": no_steps, "saturation": saturation,
                "first_level": None}
    return {"iae": total_iae(run), "steps": [m.to_dict() for m in step_metrics(run, reference)],
            "saturation": saturation, "first_level": first_level(run, reference)}


def loop_checks(table, reference, columns: LoopColumns = SIMULATED) -> list[Finding]:
    """What the run of the loop failed to do, for its status (:mod:`nfal.orchestration.checks`).

    Failures: the object never left the surface (``columns.resting`` true all along while the drive was on), or no
    level of the step reference ``reference`` reached. Warnings: each level not reached during its hold (within
    ``REACHED_BAND`` of the step into it, :func:`~nfal.models.step_metrics.level_reach`), each long saturation of
    the drive (:func:`saturation_episodes`). A structure without these columns, or a reference without steps
    (None), is not checked for them.
    """
    lift_off = _never_left_surface(table, columns)
    if lift_off is not None:
        return [lift_off]
    levels = _unreached_levels(table, reference, columns)
    if any(f.failure for f in levels):
        return levels
    return [*(Finding(f"the drive stayed saturated for {e['duration_s']:.3g} s from t = {e['start_s']:.4g} s: the "
                      f"reference {e['reference_m'] * 1e6:.4g} um is out of the film's reach with this drive limit")
              for e in saturation_episodes(table, columns=columns)), *levels]


def _never_left_surface(table, columns: LoopColumns) -> Finding | None:
    if columns.resting not in table or columns.excitation not in table:
        return None
    drive = float(np.max(table[columns.excitation]))
    if drive > 0 and np.all(np.asarray(table[columns.resting]) > 0):
        return Finding(f"the object never left the surface: {columns.resting} was true for the whole run "
                       f"({table.time[-1] - table.time[0]:g} s) while the drive reached |a| = {drive * 1e6:.3g} um",
                       failure=True)
    return None


def _unreached_levels(table, reference, columns: LoopColumns) -> list[Finding]:
    if reference is None or any(c not in table for c in (columns.height, columns.measured, columns.reference)):
        return []
    reach = level_reach(loop_run(table, columns=columns), reference)
    missed = [r for r in reach if not r.reached]
    # a level the run starts at (a band of 0: the first, from the initial height) is reached by starting there
    moved_to = [r for r in reach if r.band_m > 0]
    if moved_to and all(not r.reached for r in moved_to):
        height = np.asarray(table[columns.height])
        levels = [r.level_m for r in moved_to]
        what = "never lifted off to" if height.max() < min(r.level_m for r in reach) else "never reached"
        return [Finding(f"the object {what} the reference: its height stayed within {height.min() * 1e6:.3g}-"
                        f"{height.max() * 1e6:.3g} um, and no level "
                        f"({min(levels) * 1e6:.4g}-{max(levels) * 1e6:.4g} um) was reached in its hold", failure=True)]
    return [Finding(f"the reference's level {r.level_m * 1e6:.4g} um ({r.start_s:g}-{r.end_s:g} s) was never reached: "
                    f"the height stayed within {r.lowest_m * 1e6:.4g}-{r.highest_m * 1e6:.4g} um, not within "
                    f"{r.band_m * 1e6:.3g} um of it ({REACHED_BAND:.0%} of the step into it)") for r in missed]


def first_level(run: ClosedLoopRun, reference) -> dict:
    """The run before the first step and from it on: the highest height and the IAE of the first level (a
    rig's lift-off from rest), and the IAE of the steps [m, m s]."""
    before = run.time_s < float(reference.step_times_s[0])
    return {"peak_m": float(np.max(run.height_m[before])) if before.any() else None,
            "iae_m_s": total_iae(run, before), "steps_iae_m_s": total_iae(run, ~before)}


def saturation_episodes(table, longest_allowed_s: float = SATURATION_WARNING_S, *,
                        columns: LoopColumns = SIMULATED) -> list[dict]:
    """Every stretch in which the Controller's drive stayed saturated longer than ``longest_allowed_s``:
    its start, length and the reference then (what the film could not reach). Empty when the table has no
    ``columns.saturated`` (a controller without it) or no ``columns.reference``."""
    if columns.saturated not in table or columns.reference not in table:
        return []
    time, saturated = np.asarray(table.time), np.asarray(table[columns.saturated])
    reference = np.asarray(table[columns.reference])
    ends = np.flatnonzero((saturated[:-1] > 0) & (saturated[1:] <= saturated[:-1]))  # the run's last sample
    if saturated.size and saturated[-1] > 0:
        ends = np.append(ends, saturated.size - 1)
    return [{"start_s": float(time[i] - saturated[i]), "duration_s": float(saturated[i]),
             "reference_m": float(reference[i])} for i in ends if saturated[i] >= longest_allowed_s - 1e-12]


#: The proxy's link-health outputs summarised after a hardware-in-the-loop run (their last or worst value).
LINK_TOTALS = ("frames_dropped", "frames_lost", "rig_faults", "reconnects")


def link_summary(table) -> dict:
    """The link's health over a hardware-in-the-loop run: final counters, worst sample age and misses."""
    summary = {name: int(np.asarray(table[f"{PROXY}.{name}"])[-1]) for name in LINK_TOTALS}
    age = np.asarray(table[f"{PROXY}.measurement_age"])
    summary.update(samples_missed_max=int(np.max(table[f"{PROXY}.samples_missed"])),
                   measurement_age_max_s=float(np.max(age)), measurement_age_mean_s=float(np.mean(age)),
                   stale_steps=int(np.count_nonzero(~np.asarray(table[f"{PROXY}.fresh"], dtype=bool))))
    gaps = {f"drive_gap_{q}_s": float(np.asarray(table[f"{PROXY}.drive_gap_{q}"])[-1]) for q in ("p50", "p99", "max")
            if f"{PROXY}.drive_gap_{q}" in table}
    return {**summary, **gaps}
