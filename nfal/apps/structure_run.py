"""``nfal run``'s application: a system structure (a built-in one, by default the Fig. 7 loop, or an .ssp/.ssd
file or folder) run with what the command line asked for, the Fig. 7 loop's reference, metrics, checks, plot and
link summary chosen from the elements it has.

:class:`RunRequest` says what was asked (the parameters as text: the structure's types parse them);
:func:`run_request` assembles and runs it, and returns the result with its summary complete. The command line
parses into a request and prints the summary (nfal/cli/commands/cosim.py).
"""

from __future__ import annotations

import dataclasses
import datetime
from collections.abc import Callable, Mapping
from pathlib import Path

from nfal.apps.build import STRUCTURES, build_all
from nfal.apps.compiled_run import run_compiled
from nfal.apps.fig7 import (HARDWARE_LEAD_S, generated_reference, link_summary, loop_checks, loop_columns,
                            loop_metrics, matched_design, reference_staircase, response_panels, step_reference)
from nfal.apps.fig7_names import REFERENCE
from nfal.errors import InvalidParameterError
from nfal.orchestration import SimulationError, read_ssp, run_structure
from nfal.orchestration.resolve import resolve
from nfal.orchestration.signals import csv_signal
from nfal.orchestration.ssp import parse_boolean


@dataclasses.dataclass
class RunRequest:
    """What ``nfal run`` was asked for (None: the structure's or the reference's own)."""

    structure: str = "fig7_slow"  #: a built-in structure's name, or an .ssp/.ssd file or an unpacked folder
    parameters: Mapping[str, str] = dataclasses.field(default_factory=dict)  #: ELEMENT.VAR -> the value's text
    inputs: Mapping[str, object] = dataclasses.field(default_factory=dict)   #: ELEMENT.VAR -> a signal of time
    reference: str | None = None  #: ``staircase[:levels[:hold[:lead]]]`` or a CSV file
    reference_input: str | None = None  #: the input it drives (``none``: no reference); default Controller's
    start_time: float | None = None
    stop_time: float | None = None
    step: float | None = None
    algorithm: str = "causal"
    realtime: bool = False
    rt_priority: int | None = None
    out: Path | None = None  #: default runs/<structure>-<date-time>
    overwrite: bool = False
    max_steps: int | None = None
    build_dir: Path = Path("build")
    plot: bool = True  #: response.png for the Fig. 7 loop (about 2 s of matplotlib)
    compiled: bool = False  #: the Controller and the link run by the compiled loop (:mod:`.compiled_run`)


def run_request(request: RunRequest, notice: Callable[[str], None] = lambda text: None):
    """Run ``request``; ``notice`` gets what a user should know that is no error (a run paced because it has the
    hardware proxy, a stop time the structure decides). Returns the :class:`~nfal.orchestration.run.RunResult`
    with its summary complete (the link's health, the experiment). A run that fails raises SimulationError with
    that result (and its summary) as ``exc.result`` where there is one."""
    if request.max_steps is not None and request.max_steps < 1:
        raise InvalidParameterError("--max-steps", request.max_steps, "a whole number of steps >= 1")
    parameters = matched_design(dict(request.parameters))
    structure = _structure_path(request)
    columns, controlled, ssd_start, ssd_stop, generated = _read_structure(structure, parameters)
    if columns.hardware and not str(parameters.get("proxy.port", "")).strip():
        raise InvalidParameterError("proxy.port", None, "given: --param proxy.port=PORT, the rig's serial port (a "
                                    "device path or socket://host:port); no rig? start `nfal rig-emulator` and give "
                                    "the path it prints first")
    # in lockstep the rig's answers pace the loop (a value that is no Boolean is refused when the structure resolves)
    lockstep = parse_boolean(str(parameters.get("proxy.lockstep", "false"))) is True
    realtime = request.realtime
    if request.compiled and not columns.hardware:
        raise InvalidParameterError("--compiled", True, "a run against a rig: a structure with the hardware proxy "
                                    "(fig7_hil)")
    if request.compiled and request.algorithm != "causal":
        raise InvalidParameterError("--algorithm", request.algorithm, "not given with --compiled (no master runs)")
    if columns.hardware and not realtime and not lockstep:
        if not request.compiled:  # the compiled loop is paced by its nature
            notice("the structure has the hardware proxy: pacing it on the wall clock (--realtime)")
        realtime = True
    if request.rt_priority is not None and not realtime:
        raise InvalidParameterError("--rt-priority", request.rt_priority, "used with --realtime (a paced run)")
    driven = columns.reference  # Controller.reference, wherever the structure has its Controller
    reference_input = request.reference_input or (driven if controlled else "none")
    from_structure = request.reference is None and reference_input == driven and generated is not None
    if from_structure:  # the experiment in the archive: its ReferenceGenerator drives the reference
        reference, inputs = generated.reference, {}
        columns = dataclasses.replace(columns, reference=generated.source)
    else:
        reference = _reference(request.reference, columns.hardware, structure)
        inputs = {} if reference_input == "none" else {reference_input: reference}
    inputs.update(request.inputs)
    if request.compiled and (reference_input != driven or request.inputs or from_structure):
        raise InvalidParameterError("--compiled", True, f"the master driving {REFERENCE} alone (no --input, no "
                                    "--reference-input, no ReferenceGenerator element)")
    stop_time, note = _stop_time(request.stop_time, ssd_stop, reference if reference_input != "none" else None)
    start = request.start_time if request.start_time is not None else ssd_start
    if note and stop_time > start:  # else the run is refused for it, and the note would only come first
        notice(note)
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    out = request.out if request.out is not None else Path("runs") / f"{structure.stem}-{stamp}"
    fig7 = reference_input == driven
    steps, no_steps = step_reference(reference, start, stop_time) if fig7 and stop_time is not None else (None, None)
    metrics = (lambda table: loop_metrics(table, steps, columns, no_steps=no_steps)) if fig7 else None
    experiment = {"reference": generated.source if from_structure else (reference_input if fig7 else None),
                  "stop_time_note": note}
    plot = (response_panels(columns) if fig7 else None) if request.plot else False
    common = dict(start_time=request.start_time, stop_time=stop_time, step_size=request.step, parameters=parameters,
                  out_dir=out, rt_priority=request.rt_priority, overwrite=request.overwrite,
                  max_steps=request.max_steps, plot=plot, metrics=metrics,
                  checks=lambda table: loop_checks(table, steps, columns))
    try:
        if request.compiled:
            result = run_compiled(structure, reference=inputs.pop(reference_input), **common)
        else:
            result = run_structure(structure, inputs=inputs, algorithm=request.algorithm, realtime=realtime, **common)
    except SimulationError as exc:
        if exc.result is not None:
            _complete(exc.result, columns, experiment)
        raise
    _complete(result, columns, experiment)
    return result


def _complete(result, columns, experiment: dict) -> None:
    """The summary's last entries: the link's health (against hardware) and the experiment."""
    if columns.hardware and result.csv_path.is_file() and result.summary.get("steps_completed"):
        result.update_summary(link=link_summary(result.table()))
    result.update_summary(experiment=experiment)


def _structure_path(request: RunRequest) -> Path:
    if request.structure in STRUCTURES:
        return build_all(request.build_dir, structures=(request.structure,))[request.structure]
    path = Path(request.structure)
    if not path.exists():
        raise InvalidParameterError("structure", request.structure,
                                    f"one of {', '.join(STRUCTURES)} or an existing .ssp/.ssd/folder "
                                    f"(nothing is at {path.absolute()})")
    return path


def _reference(spec: str | None, hardware: bool, structure: Path):
    spec = spec or "staircase"
    staircase = reference_staircase(spec, structure.stem, HARDWARE_LEAD_S if hardware else None)
    return csv_signal(spec) if staircase is None else staircase


def _read_structure(structure: Path, parameters: dict):
    """(the loop's columns where the structure has them, whether it has a Controller, the DefaultExperiment's start
    time (0 if none) and stop time (or None), the GeneratedReference or None)."""
    with read_ssp(structure) as read:
        names = [name for name, _ in read.system.components()]
        columns = loop_columns(names)
        controlled = columns.reference.rpartition(".")[0] in names  # Controller.reference, located
        start, stop = read.default_experiment.start_time or 0.0, read.default_experiment.stop_time
        generated = generated_reference(resolve(read, parameters), columns.reference) if controlled else None
    return columns, controlled, start, stop, generated


def _stop_time(asked: float | None, ssd_stop: float | None, reference) -> tuple[float | None, str | None]:
    """The run's stop time and a note where the structure's and the reference's differ: ``asked`` (--stop-time),
    else the SSD's DefaultExperiment stopTime, else the reference's length (the staircase is a default only where
    the SSD says nothing)."""
    length = getattr(reference, "duration_s", None) if reference is not None else None
    if asked is not None:
        return asked, None
    if ssd_stop is None:
        return length, None
    if length is not None and abs(length - ssd_stop) > 1e-9 * max(1.0, length):
        where = "before the reference's end" if ssd_stop < length else "after the reference's last change"
        return ssd_stop, (f"the structure's DefaultExperiment stopTime ({ssd_stop:g} s) governs, {where}: "
                          f"the reference lasts {length:g} s (--stop-time {length:g} runs all of it)")
    return ssd_stop, None
