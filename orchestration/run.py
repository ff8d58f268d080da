"""``run_structure``: read an SSP, run it with the fixed-step master, and write the results.

Writes into ``out_dir``: ``results.csv`` (streamed while the run goes), ``summary.json`` (written
with status "running" before the first step, rewritten at the end: "ok", "ok" with ``warnings``,
"failed" or "interrupted", :mod:`.checks`) and ``response.png``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import logging
import math
import os
import sys
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

from tqdm import tqdm

from nfal.errors import (InvalidParameterError, ResultsExistError, RunCheckError, SimulationError, require_finite,
                         require_positive)
from nfal.realtime import SlackCollector, realtime_section

from .checks import Finding, judge
from .interrupts import deferred_interrupts
from .master import ALGORITHMS, HorizonEnd, Master
from .pacing import RealTimePacer, prompt_thread_switching, realtime_priority, require_realtime_priority
from .resolve import resolve
from .results import CsvWriter, PlotPanel, ResultTable, plot_response, read_results, write_summary
from .signals import PiecewiseConstant
from .ssp import read_ssp

logger = logging.getLogger(__name__)

RESULTS_CSV, SUMMARY_JSON, RESPONSE_PNG = "results.csv", "summary.json", "response.png"

#: The most communication steps a run takes unless told otherwise: 5000 s of Fig. 7 at 2 kHz, a
#: results.csv of about 1 GB. A mistyped --stop-time 1e9 or --step 1e-9 is refused before it starts.
MAX_STEPS = 10_000_000


@dataclasses.dataclass
class RunResult:
    """What a run wrote: the folder, its files and the summary (also in ``summary.json``).

    ``table()`` (or ``result["Plant.height"]``) reads the CSV back as arrays.
    """

    out_dir: Path
    csv_path: Path
    summary_path: Path
    plot_path: Path | None
    summary: dict
    _table: ResultTable | None = dataclasses.field(default=None, repr=False)

    def table(self) -> ResultTable:
        """The results, read from the CSV (once)."""
        if self._table is None:
            self._table = read_results(self.csv_path)
        return self._table

    def __getitem__(self, name: str):
        return self.table()[name]

    def update_summary(self, **entries) -> None:
        """Add entries (e.g. metrics computed afterwards) to the summary and rewrite ``summary.json``."""
        self.summary.update(entries)
        write_summary(self.summary_path, self.summary)


def _step_count(start: float, stop: float, step: float) -> int:
    ratio = (stop - start) / step
    count = round(ratio)
    whole = abs(ratio - count) <= 1e-9 * max(1.0, ratio)
    if not whole:
        count = math.floor(ratio + 1e-9)
    if count < 1:  # before any warning that the run ends early: it does not run
        raise InvalidParameterError("stop_time", stop,
                                    f"at least one step ({step:g} s) after the start time {start:g} s")
    if not whole:
        logger.warning("stop time %g s is not a whole number of %g s steps from %g s: the run ends at %g s",
                       stop, step, start, start + count * step)
    return count


def _horizon_note(ended: HorizonEnd, end_time: float) -> dict:
    """Summary entries for a run that an FMU ended at its own horizon (not a failure)."""
    return {"ended_early": {"element": ended.element, "fmu_last_successful_time_s": ended.time_s,
                            "run_end_time_s": end_time, "messages": list(ended.messages)},
            "note": ended.note}

def _require_step_count(steps: int, stop: float, step: float, max_steps: int) -> None:
    if steps > max_steps:
        raise InvalidParameterError(
            "stop_time / step_size", f"{stop:g} s / {step:g} s",
            f"at most {max_steps:,} steps, not {steps:,} (one results row each); check the units, or allow "
            "more with --max-steps (run_structure's max_steps)")


def claim_results_folder(out: Path, overwrite: bool) -> None:
    """Create ``out``; refuse it if it holds a previous run's files, unless ``overwrite`` (then remove them,
    so that a run failing at start-up leaves no older plot or summary beside its own)."""
    ours = [out / name for name in (RESULTS_CSV, SUMMARY_JSON, RESPONSE_PNG) if (out / name).exists()]
    if ours and not overwrite:
        raise ResultsExistError(f"{out} already holds {', '.join(p.name for p in ours)}: give a new --out folder, "
                                "or --overwrite to replace them")
    out.mkdir(parents=True, exist_ok=True)
    for path in ours:
        path.unlink()


def _panels(plot) -> list[PlotPanel] | None:
    if plot is None:
        return None
    panels = []
    for panel in plot:
        panels.append(panel if isinstance(panel, PlotPanel) else PlotPanel(tuple([panel] if isinstance(panel, str)
                                                                                 else panel)))
    return panels


def _describe(source: object) -> object:
    if isinstance(source, PiecewiseConstant):
        return source.describe()
    if isinstance(source, (int, float)):
        return source
    return repr(source)


def run_structure(path: str | os.PathLike, *, stop_time: float | None = None, step_size: float | None = None,
                  start_time: float | None = None, inputs: Mapping[str, object] | None = None,
                  parameters: Mapping[str, object] | None = None, algorithm: str = "causal",
                  out_dir: str | os.PathLike | None = None, realtime: bool | float = False,
                  progress: bool | None = None, plot: Sequence | bool | None = None,
                  metrics: Callable[[ResultTable], Mapping] | None = None,
                  checks: Callable[[ResultTable], Sequence[Finding]] | None = None,
                  undeclared_dependencies: str = "none",
                  fmu_logging: str = "on", flush_interval_s: float = 0.25, rt_priority: int | None = None,
                  overwrite: bool = False, max_steps: int | None = None) -> RunResult:
    """Run an SSP 1.0 system structure of FMI 2.0 and FMI 3.0 co-simulation FMUs (mixed at will) with a fixed step.

    Parameters
    ----------
    path : path-like
        An ``.ssp`` archive, an SSP folder or an ``.ssd`` file.
    stop_time, step_size, start_time : float, optional
        [s]. Default: the SSD's DefaultExperiment (step size: its OSP FixedStepAlgorithm annotation);
        start 0. An error if neither gives a stop time or step size.
    inputs : mapping, optional
        External inputs: ``"Element.variable"`` or a top-level system input connector -> a function
        of time (e.g. :func:`~nfal.orchestration.signals.staircase`, a ``Staircase``) or a constant.
        An input that a connection feeds is driven from here instead (the connection is replaced).
    parameters : mapping, optional
        ``"Element.variable"`` -> value, applied after the SSD's parameter bindings. Strings are parsed
        by the variable's type.
    algorithm : {"causal", "jacobi"}
        See :mod:`nfal.orchestration.master`.
    out_dir : path-like, optional
        Result folder (created); default a new temporary folder. Refused (:class:`ResultsExistError`)
        if it holds a previous run's results.csv, summary.json or response.png, unless ``overwrite``.
    overwrite : bool
        Replace (first remove) a previous run's files in ``out_dir``.
    max_steps : int, optional
        Refuse a run of more communication steps (default :data:`MAX_STEPS`).
    realtime : bool or float
        True: release step k at wall time t0 + k dt and report overruns and jitter
        (:mod:`nfal.orchestration.pacing`); a number: the same at that many simulated seconds per wall
        second. A release starts the step's doStep calls; the exchange at t_{k+1} (``causal``: the
        sweep; ``jacobi``: reading the outputs) follows them at once, within the same step's budget.
        While paced, the thread switch interval is 50 us (:func:`~.pacing.prompt_thread_switching`).
    rt_priority : int, optional
        With ``realtime``: run the paced loop under SCHED_FIFO at this priority (1-99,
        :func:`~.pacing.realtime_priority`), so that other processes do not delay its releases. Refused
        (:class:`~.pacing.RealtimePriorityError`) before anything runs if the system does not allow it.
    progress : bool, optional
        A tqdm bar on stderr; default: only when stderr is a terminal.
    plot : sequence of PlotPanel (or of column-name sequences), False, or None
        The panels of ``response.png``; None: every column grouped by unit; False: no plot.
    metrics : callable, optional
        ``metrics(table) -> dict``, evaluated after a successful run; stored as ``summary["metrics"]``.
    checks : callable, optional
        ``checks(table) -> findings``, evaluated after a successful run: warnings go to ``summary["warnings"]``
        (the status stays "ok"), a failure makes the status "failed" (:mod:`.checks`).
    undeclared_dependencies : {"none", "all"}
        How to read outputs that declare no dependencies (:mod:`nfal.orchestration.resolve`).
    fmu_logging : {"on", "off"}
        Instantiate the FMUs with logging on or off (:class:`~nfal.orchestration.master.Master`).
    flush_interval_s : float
        Longest wall time between CSV flushes [s].

    Returns
    -------
    RunResult
        An FMU that ends its own horizon (fmi2Discard from doStep, then fmi2Terminated) ends the run
        at its last complete communication point: status "ok", ``note`` and ``ended_early`` in the summary.

    Raises
    ------
    StructureError (ValueError)
        The structure cannot be run (before anything is written): unknown element or connector, unit
        or type mismatch, causality, algebraic loop (``causal``), missing FMU.
    SimulationError (RuntimeError)
        An FMU failed during the run; ``error.result`` is the :class:`RunResult` of what was written
        (every row up to the failure, and a summary with status "failed"). :class:`RunCheckError` (a
        SimulationError) if the run completed but one of ``checks`` failed.
    """
    if algorithm not in ALGORITHMS:
        raise InvalidParameterError("algorithm", algorithm, f"one of {ALGORITHMS}")
    speed = _pacing_speed(realtime, rt_priority)
    started_at = datetime.datetime.now().astimezone().isoformat(timespec="seconds")
    with read_ssp(path) as structure:
        system = resolve(structure, parameters, undeclared_dependencies=undeclared_dependencies)
        start, step, steps = experiment_steps(structure.default_experiment, start_time, stop_time, step_size,
                                         MAX_STEPS if max_steps is None else max_steps)
        master = Master(system, step_size=step, algorithm=algorithm, inputs=inputs, fmu_logging=fmu_logging)
        out = Path(out_dir) if out_dir is not None else Path(tempfile.mkdtemp(prefix="nfal-run-"))
        claim_results_folder(out, overwrite)
        summary = opening_summary(path, system, master, algorithm, start, step, steps, started_at, inputs,
                                   parameters, rt_priority)
        summary_path = write_summary(out / SUMMARY_JSON, summary)
        writer = CsvWriter(out / RESULTS_CSV, master.columns, flush_interval_s=flush_interval_s)
        pacer = RealTimePacer(step, speed=speed) if speed else None
        show = progress if progress is not None else sys.stderr.isatty()
        with tqdm(total=steps, disable=not show, file=sys.stderr, unit="step", desc=system.name, leave=False,
                  mininterval=0.25) as bar:
            loop = _run_loop(master, writer, start, step, steps, pacer, rt_priority, bar)
        summary.update(_closing_summary(loop, master, writer, start, step, pacer))
        return finish_run(RunResult(out, out / RESULTS_CSV, summary_path, None, summary), loop.error, plot=plot,
                          metrics=metrics, checks=checks, title=f"{system.name} ({algorithm}, {step:g} s)")


def finish_run(result: RunResult, error: BaseException | None, *, plot, metrics, checks, title: str) -> RunResult:
    """What follows a run's loop (ours, or another engine's that wrote the same files): the plot, the metrics and the
    checks (on a run that completed), ``summary.json`` rewritten; then ``error`` (the loop's) or a failed check raised
    with ``result`` attached, or ``result`` returned. ``plot``, ``metrics`` and ``checks`` as :func:`run_structure`."""
    summary = result.summary
    if plot is not False and summary.get("rows_written"):
        _plot(result, plot, title=title)
    if metrics is not None and error is None:
        _evaluate_metrics(result, metrics)
    failed_check = _evaluate_checks(result, checks) if checks is not None and error is None else None
    write_summary(result.summary_path, summary)
    logger.info("%s: %s, %d of %d steps in %.3f s wall time -> %s", summary["system"], summary["status"],
                summary["steps_completed"], summary["steps"], summary["wall_time_s"], result.out_dir)
    if error is not None:
        if isinstance(error, SimulationError):
            error.result = result
        raise error
    if failed_check is not None:
        failed_check.result = result
        raise failed_check
    return result


def _pacing_speed(realtime: bool | float | None, rt_priority: int | None) -> float:
    """Simulated seconds per wall second of a paced run (0: unpaced); a refused priority is refused now,
    before anything is written, rather than mid-run."""
    speed = 0.0
    if realtime is True:
        speed = 1.0
    elif realtime is not False and realtime is not None:
        speed = require_positive("realtime", realtime)
    if rt_priority is not None:
        if not speed:
            raise InvalidParameterError("rt_priority", rt_priority, "given only with realtime (a paced run)")
        require_realtime_priority(rt_priority)
    return speed


def experiment_steps(experiment, start_time: float | None, stop_time: float | None, step_size: float | None,
                max_steps: int) -> tuple[float, float, int]:
    """(start, step, number of steps): the arguments where given, else the SSD's DefaultExperiment."""
    start = float(start_time if start_time is not None else (experiment.start_time or 0.0))
    stop = stop_time if stop_time is not None else experiment.stop_time
    step = step_size if step_size is not None else experiment.step_size
    if stop is None:
        raise InvalidParameterError("stop_time", None, "given (nfal run --stop-time S), since the SSD has no "
                                    "DefaultExperiment stopTime")
    if step is None:
        raise InvalidParameterError("step_size", None, "given (nfal run --step S), since the SSD has no OSP "
                                    "FixedStepAlgorithm baseStepSize annotation (the step annotations of other tools "
                                    "are not read)")
    step = require_positive("step_size", step)
    steps = _step_count(require_finite("start_time", start), require_finite("stop_time", stop), step)
    _require_step_count(steps, float(stop), step, max_steps)
    return start, step, steps


def opening_summary(path, system, master: Master, algorithm: str, start: float, step: float, steps: int,
                     started_at: str, inputs, parameters, rt_priority) -> dict:
    """The summary as written before the first step (status "running")."""
    return {
        "structure": str(path), "system": system.name, "algorithm": algorithm, "start_time_s": start,
        "stop_time_s": start + steps * step, "step_size_s": step, "steps": steps, "steps_completed": 0,
        "status": "running", "error": None, "started_at": started_at,
        "elements": {e.name: {"fmu": str(e.source), "start_values": dict(e.start_values)} for e in system.elements},
        "connections": [f"{link.source.path} -> {link.target.path}" for link in system.links],
        "exchange_order": master.order, "inputs": {k: _describe(v) for k, v in dict(inputs or {}).items()},
        "rt_priority": rt_priority, "parameters": dict(parameters or {}),
        "unmatched_parameters": list(system.unmatched_parameters),
        "columns": [c.header for c in master.columns], "results_csv": RESULTS_CSV,
    }


@dataclasses.dataclass
class _LoopOutcome:
    """What the stepping loop did: steps completed, the error that stopped it (None: it finished), times [s]."""

    completed: int = 0
    error: BaseException | None = None
    init_time_s: float = 0.0
    loop_time_s: float = 0.0
    wall_time_s: float = 0.0
    timing: dict = dataclasses.field(default_factory=dict)
    collector: SlackCollector | None = None  #: the real-time section's (paced runs)


def _run_loop(master: Master, writer: CsvWriter, start: float, step: float, steps: int,
              pacer: RealTimePacer | None, rt_priority: int | None, bar) -> _LoopOutcome:
    """Instantiate, initialise and step the master, writing each row; every error is caught into the outcome
    (the CSV closed, every row up to it kept)."""
    outcome = _LoopOutcome()
    chunk = max(1, steps // 500)
    wall_start = time.perf_counter()
    try:
        with master, deferred_interrupts() as stop_request:
            master.instantiate()
            master.initialize(start, start + steps * step)
            writer.write(master.row)
            row = master.row
            with (prompt_thread_switching() if pacer is not None else contextlib.nullcontext(),
                  realtime_priority(rt_priority),
                  realtime_section() if pacer is not None else contextlib.nullcontext() as collector):
                outcome.collector = collector
                if collector is not None:
                    collector.settle()  # everything set up so far frozen, before the first step
                outcome.init_time_s = time.perf_counter() - wall_start  # the section's set-up included
                loop_start = time.perf_counter()
                if pacer is not None:
                    pacer.start()
                for k in range(steps):
                    if pacer is not None:
                        pacer.wait(k)
                    master.step()
                    if pacer is not None:
                        pacer.done(k)
                    if master.ended is not None and not master.ended.step_completed:
                        break
                    writer.write(row)
                    if collector is not None:
                        collector.safe_point()  # the step is done: slack until the next release
                    outcome.completed = k + 1
                    stop_request.check()
                    if outcome.completed % chunk == 0:
                        bar.update(chunk)
                    if master.ended is not None:
                        break
                if pacer is not None and master.ended is None:
                    pacer.sleep_until(steps)
            outcome.loop_time_s = time.perf_counter() - loop_start
            outcome.timing = master.timing()
    except BaseException as exc:  # noqa: BLE001 - recorded in the summary, then re-raised by run_structure
        outcome.error = exc
        outcome.loop_time_s = time.perf_counter() - wall_start - outcome.init_time_s
        outcome.timing = master.timing()
    finally:
        try:
            writer.close()
        except OSError as exc:  # e.g. a full disk on the last flush: the run failed, and the summary says why
            outcome.error = outcome.error or exc
    outcome.wall_time_s = time.perf_counter() - wall_start
    return outcome


def loop_summary(error: BaseException | None, completed: int, start: float, step: float, rows: int, wall_time_s: float,
                 init_time_s: float, loop_time_s: float) -> dict:
    """The summary's entries any engine's loop gives once it has ended: status, how far it got, its times."""
    return {
        "status": "ok" if error is None else ("interrupted" if isinstance(error, KeyboardInterrupt) else "failed"),
        "error": None if error is None else str(error) or type(error).__name__, "warnings": [],
        "steps_completed": completed, "end_time_s": start + completed * step, "rows_written": rows,
        "wall_time_s": wall_time_s, "initialization_wall_time_s": init_time_s, "loop_wall_time_s": loop_time_s,
        "real_time_factor": (completed * step) / loop_time_s if loop_time_s > 0 else None,
    }


def _closing_summary(loop: _LoopOutcome, master: Master, writer: CsvWriter, start: float, step: float,
                     pacer: RealTimePacer | None) -> dict:
    """The summary's entries once the loop has ended: status, how far it got, timing, and why it stopped."""
    error, completed, loop_time = loop.error, loop.completed, loop.loop_time_s
    do_step_total = sum(t["do_step_total_s"] for t in loop.timing.values())
    entries = {
        **loop_summary(error, completed, start, step, writer.rows, loop.wall_time_s, loop.init_time_s, loop_time),
        "do_step_wall_time_s": do_step_total, "exchange_engine": master.engine,
        "exchange_and_record_us_per_step": (loop_time - do_step_total) / completed * 1e6 if completed else None,
        "timing": loop.timing,
        "realtime": None if pacer is None else {**pacer.report(),
                                                **(loop.collector.report() if loop.collector is not None else {})},
    }
    if master.ended is not None:
        entries.update(_horizon_note(master.ended, entries["end_time_s"]))
    if error is not None and hasattr(error, "element"):
        entries["error_detail"] = {"element": error.element, "function": error.function, "status": error.status,
                                   "time_s": error.time, "messages": list(error.messages)}
    return entries


def _plot(result: RunResult, plot, title: str) -> None:
    try:
        result.plot_path = plot_response(result.table(), result.out_dir / RESPONSE_PNG, _panels(plot), title=title)
        result.summary["plot"] = RESPONSE_PNG
    except Exception as exc:  # a plot must not hide the run's own outcome
        logger.warning("no plot: %s", exc)
        result.summary["plot_error"] = str(exc)


def _evaluate_metrics(result: RunResult, metrics: Callable[[ResultTable], Mapping]) -> None:
    try:
        result.summary["metrics"] = dict(metrics(result.table()))
    except Exception as exc:
        logger.warning("metrics failed: %s", exc)
        result.summary["metrics_error"] = f"{type(exc).__name__}: {exc}"


def _evaluate_checks(result: RunResult, checks: Callable[[ResultTable], Sequence[Finding]]) -> RunCheckError | None:
    try:
        findings = checks(result.table())
    except Exception as exc:  # a check that breaks must not hide the run's own outcome
        logger.warning("checks failed: %s", exc)
        result.summary["checks_error"] = f"{type(exc).__name__}: {exc}"
        return None
    return judge(result.summary, findings)
