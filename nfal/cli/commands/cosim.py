"""``nfal build`` (FMUs and SSP archives) and ``nfal run`` (a system structure, by default the Fig. 7 loop)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from nfal.apps.build import RIG_STRUCTURES, STRUCTURES, build_all
from nfal.apps.fig7 import reference_staircase
from nfal.apps.fig7_names import REFERENCE
from nfal.apps.structure_run import RunRequest, run_request
from nfal.cli.commands import COMMANDS
from nfal.cli.commands.common import finite_float, positive_float, print_json, print_step_table, steal_text
from nfal.errors import InvalidParameterError
from nfal.fmus.build import FMU_SCRIPTS
from nfal.fmus.windows_python import windows_python
from nfal.hil.link import DRIVE_GAP_BUDGET_S
from nfal.orchestration import SimulationError
from nfal.orchestration.signals import signal_from_spec


def register(commands) -> None:
    _register_build(commands)
    _register_run(commands)


def _register_build(commands) -> None:
    build = commands.add_parser(
        "build", help=COMMANDS["build"].summary,
        description=f"Build every FMU ({', '.join(FMU_SCRIPTS)}) with pythonfmu, self-contained, and pack "
        f"{', '.join(f'{name}.ssp' for name in STRUCTURES)} and the rig emulator's "
        f"{' and '.join(f'{name}.ssp' for name in RIG_STRUCTURES)} (SSP 1.0). FMUs newer than their sources are kept.")
    build.add_argument("--out", default="build", metavar="DIR", help="output folder (default build/)")
    build.add_argument("--fmi", type=int, choices=(2, 3), default=2,
                       help="FMI version: 2 (default) or 3 (the same FMUs as FMI 3.0 co-simulation FMUs, with "
                       "pythonfmu3, and the same SSP archives wired to them, into DIR/fmi3/: `nfal run "
                       "DIR/fmi3/fig7_slow.ssp` runs them)")
    build.add_argument("--platform", choices=("linux", "win64"), default="linux",
                       help="linux (default): Linux x86-64 binaries; win64: Windows x86-64 binaries too, beside them "
                       "(one FMU serves both), cross-compiled with mingw-w64 (apt-get install "
                       "g++-mingw-w64-x86-64-posix). The Windows binaries start the Windows Python of "
                       "--windows-python, recorded in the FMU's resources/python-win64.cfg")
    build.add_argument("--windows-python", metavar="DIR",
                       help="with --platform win64: the root of a Windows CPython (python.exe, python3.dll, "
                       "include/) with numpy, scipy, numba and control; default: one nfal prepares from PyPI "
                       "in its cache on first use (CPython 3.11 for Windows and its win_amd64 wheels, ~1 min). "
                       "Its path is recorded as wine sees it (Z:\\...); on Windows, point the FMU at a Python "
                       "with override= in python-win64.cfg or NFAL_FMU_PYTHON")
    build.add_argument("--json", action="store_true", help="print the built archives as JSON")
    build.set_defaults(handler=run_build)


def _register_run(commands) -> None:
    run = commands.add_parser(
        "run", help=COMMANDS["run"].summary,
        description="Run an SSP system structure with the fixed-step master over fmpy. Without STRUCTURE, builds "
        "what is missing and runs fig7_slow (gain-scheduled PID, slow plant, resonance tracker, sensor chain) on the "
        "reference of Figs. 9-10, writing runs/<name>/results.csv, summary.json and response.png, and printing the "
        "step metrics. The experiment is the structure's: its ReferenceGenerator element drives Controller.reference "
        "(the staircase, as its parameters say) unless --reference is given, and start, stop and step come from its "
        "ssd:DefaultExperiment (startTime, stopTime; the step from its OSP FixedStepAlgorithm baseStepSize annotation) "
        "unless --start-time, --stop-time or --step is given; the reference's own length is the stop time only where "
        "the structure has none, and a run says so where the two differ. FMI 2.0 and FMI 3.0 co-simulation FMUs, "
        "mixed at will. An FMU that ends its own horizon (fmi2Discard, then fmi2Terminated; FMI 3.0: "
        "terminateSimulation) ends the run there, with a note. A Fig. 7 run is checked: an object that never leaves "
        "the surface or reaches no level of its reference fails the run (exit 2, the reason, every row kept); a level "
        "never reached, or a long saturation of the drive, is a warning (status ok; docs/cosimulation.md, \"A run's "
        "status and its step metrics\"). The master makes each step's FMI calls from C, built with the system's C "
        "compiler on first use (summary.json's exchange_engine says C or Python; NFAL_COMPILED_EXCHANGE=off: from "
        "Python, the same results).",
        epilog="Examples: nfal run; nfal run fig7_reynolds --stop-time 0.7; "
        "nfal run build/fig7_slow.ssp --param Controller.design=fixed --param Controller.design_height=120e-6; "
        "nfal run --reference my_reference.csv --realtime; "
        "hardware in the loop against `nfal rig-emulator` or the rig: "
        "nfal run fig7_hil --param proxy.port=/dev/ttyACM0 --realtime")
    run.add_argument("structure", nargs="?", default="fig7_slow",
                     help="a built-in structure (fig7_slow, fig7_reynolds, fig7_hil) or an .ssp archive, .ssd file or "
                     "SSP folder (default fig7_slow)")
    run.add_argument("--start-time", type=finite_float, metavar="S",
                     help="start time [s] (default: the structure's DefaultExperiment startTime, else 0)")
    run.add_argument("--stop-time", type=positive_float, metavar="S",
                     help="stop time [s] (default: the structure's DefaultExperiment stopTime: 3.7 s for fig7_slow and "
                     "fig7_reynolds, 4.6 s for fig7_hil; where it has none, the reference's length)")
    run.add_argument("--step", type=positive_float, metavar="S", help="communication step [s] (default: the "
                     "structure's DefaultExperiment FixedStepAlgorithm baseStepSize annotation, 5e-4 s (2 kHz) for "
                     "Fig. 7)")
    run.add_argument("--param", action="append", default=[], metavar="ELEMENT.VAR=VALUE",
                     help="override a parameter or start value (repeatable)")
    run.add_argument("--reference", metavar="staircase[:L1,L2,...[:HOLD[:LEAD]]]|FILE.csv",
                     help="drive Controller.reference from the master instead of the structure's ReferenceGenerator "
                     "(its connection is replaced): the built-in staircase of Figs. 9-10 (60-180 um; against hardware "
                     "its first level is held 1 s, for lift-off from rest; fig7_reynolds: 60-100 um, what the film of "
                     "the Fig. 3 stand-in holds with |a| <= 10 um), your own staircase (levels m, holds s) or a CSV of "
                     "time_s,reference_m (held between rows); step metrics for a staircase and for a CSV of steps "
                     "(levels held 50 ms or more), the IAE alone otherwise. Default: the structure's "
                     "ReferenceGenerator (its parameters: --param ReferenceGenerator.levels=... etc.; "
                     "docs/cosimulation.md), or the built-in staircase in a structure without one. With --param "
                     "Plant.shape=SHAPE the Controller is designed on that film (calibration perturbation:SHAPE) "
                     "unless Controller.calibration is given")
    run.add_argument("--reference-input", metavar="ELEMENT.VAR",
                     help=f"the input the reference drives (default {REFERENCE} if the structure has a Controller "
                     "element, else none; 'none' for no external input)")
    run.add_argument("--input", action="append", default=[], metavar="ELEMENT.VAR=SIGNAL",
                     help="drive another input, of an element or the system's (repeatable): SIGNAL is constant:V, "
                     "step:INITIAL,FINAL,AT_S, "
                     "staircase:L1,L2,...[:HOLD[:LEAD]] or a CSV of time_s,value; e.g. "
                     "ResonanceTracker.resonance_shift=step:0,57,1.0 (a 0.2 %% resonance drift at 1 s)")
    run.add_argument("--algorithm", choices=("causal", "jacobi"), default="causal",
                     help="causal: outputs propagated in feedthrough order at each step, then all FMUs step (default); "
                     "jacobi: all step, then outputs move to inputs (as OSP libcosim does)")
    run.add_argument("--realtime", action="store_true", help="release steps on the wall clock; report overruns and "
                     "step-start jitter (p50/p99/max) in summary.json (on by itself for a structure with the hardware "
                     "proxy)")
    run.add_argument("--rt-priority", type=int, metavar="1-99", help="with --realtime (on by itself against hardware): "
                     "run the paced loop under SCHED_FIFO at this priority, so other processes cannot delay its steps "
                     "(Linux; needs root, CAP_SYS_NICE or an rtprio limit; e.g. 50)")
    run.add_argument("--compiled", action="store_true", help="against a rig (fig7_hil): run the Controller's law and "
                     "the link in the compiled 2 kHz loop (C, on a thread that waits for no Python) instead of "
                     "stepping the two FMUs; the same parameters, columns and summary (docs/hil.md, \"The compiled "
                     "loop\"; needs cc and make)")
    run.add_argument("--out", metavar="DIR", help="result folder (default runs/<structure>-<date-time>); refused if it "
                     "holds a previous run's results.csv, summary.json or response.png, unless --overwrite")
    run.add_argument("--overwrite", action="store_true", help="replace the results of a previous run in --out")
    run.add_argument("--max-steps", type=int, metavar="N", help="refuse a run of more communication steps than this "
                     "(default 10 000 000: about 1 GB of results for Fig. 7)")
    run.add_argument("--build-dir", default="build", metavar="DIR",
                     help="where built-in structures are built (default build/)")
    run.add_argument("--json", action="store_true", help="print the summary as JSON")
    run.add_argument("--no-plot", dest="plot", action="store_false",
                     help="no response.png (the Fig. 7 loop's plot: about 2 s of a short run)")
    run.set_defaults(handler=run_cosimulation)


def run_build(args: argparse.Namespace) -> int:
    if args.windows_python and args.platform != "win64":
        raise InvalidParameterError("--windows-python", args.windows_python, "given with --platform win64")
    python = windows_python(args.windows_python) if args.platform == "win64" else None
    out = Path(args.out) if args.fmi == 2 else Path(args.out) / "fmi3"
    archives = build_all(out, fmi_version=args.fmi, windows_python=python)
    if args.json:
        print_json({name: str(path) for name, path in archives.items()})
    else:
        for name, path in archives.items():
            print(f"{name}: {path}")
    return 0


def parse_parameter(text: str) -> tuple[str, str]:
    """``Element.var=value`` -> (name, value text): the variable's type parses the text when the structure is
    resolved (:func:`~nfal.orchestration.resolve.coerce_value`), so ``60e-6`` stays ``60e-6`` for a String."""
    name, sep, value = text.partition("=")
    if not sep or "." not in name.strip(".") or not value.strip():
        raise InvalidParameterError("--param", text, "ELEMENT.VAR=VALUE")
    return name.strip(), value.strip()


def parse_input(text: str) -> tuple[str, object]:
    """``Element.var=SIGNAL`` -> (name, signal of time): a staircase as ``--reference`` takes it
    (:func:`~nfal.apps.fig7.reference_staircase`), else as :func:`~nfal.orchestration.signals.signal_from_spec`
    reads it."""

    name, sep, spec = text.partition("=")
    if not sep or not name.strip() or not spec:  # the master names the inputs there are if NAME is none
        raise InvalidParameterError("--input", text, "ELEMENT.VAR=SIGNAL (or a system input's NAME=SIGNAL)")
    return name.strip(), reference_staircase(spec.strip(), "") or signal_from_spec(spec.strip())


def run_cosimulation(args: argparse.Namespace) -> int:
    request = RunRequest(structure=args.structure, parameters=dict(parse_parameter(text) for text in args.param),
                         inputs=dict(parse_input(text) for text in args.input), reference=args.reference,
                         reference_input=args.reference_input, start_time=args.start_time, stop_time=args.stop_time,
                         step=args.step, algorithm=args.algorithm, realtime=args.realtime, rt_priority=args.rt_priority,
                         out=Path(args.out) if args.out else None, overwrite=args.overwrite, max_steps=args.max_steps,
                         build_dir=Path(args.build_dir), plot=args.plot, compiled=args.compiled)
    try:
        result = run_request(request, notice=lambda text: print(f"nfal run: {text}", file=sys.stderr))
    except SimulationError as exc:
        if exc.result is not None:
            _report(exc.result.summary, exc.result.out_dir, args.json)
        raise
    _report(result.summary, result.out_dir, args.json)
    return 0


def _report(summary: dict, out: Path, as_json: bool) -> None:
    if as_json:
        print_json(summary)
    else:
        _print_summary(summary, out)


def _status_text(summary: dict) -> str:
    """The status as a person reads it: ok, ok with N warnings, failed (the reason is printed last, on stderr)."""
    warnings = len(summary.get("warnings") or ())
    if summary.get("status", "ok") != "ok":
        return f"{summary.get('status')}: the reason is below"
    return f"ok with {warnings} warning{'s' * (warnings > 1)}" if warnings else "ok"


def _print_summary(summary: dict, out: Path) -> None:
    status = _status_text(summary)
    if status != "ok" and summary.get("steps_completed") != summary.get("steps"):  # stopped by an error
        print(f"{summary.get('structure')}: {summary.get('status')} after {summary.get('steps_completed')} of "
              f"{summary.get('steps')} steps; the results up to there are in {out}")
        return
    print(f"{summary.get('structure')}: {summary.get('end_time_s', summary.get('stop_time_s')):g} s in "
          f"{summary.get('wall_time_s', 0.0):.2f} s wall time ({summary.get('algorithm')}, "
          f"step {summary.get('step_size_s'):g} s) -> {out}"
          + ("" if status == "ok" else f" ({status})"))
    if summary.get("note"):
        print(f"note: {summary['note']}")
    metrics = summary.get("metrics")
    if metrics:
        first = metrics.get("first_level") or {}
        parts = (f": {first['iae_m_s'] * 1e6:.3f} on the first level (its peak {first['peak_m'] * 1e6:.1f} um), "
                 f"{first['steps_iae_m_s'] * 1e6:.3f} over the steps" if first.get("peak_m") is not None else "")
        print(f"IAE {metrics['iae'] * 1e6:.3f} um s{parts}")
        if metrics["steps"] is not None:
            print_step_table(metrics["steps"])
        else:
            print(f"no step table: {metrics.get('no_steps')}")
    for warning in summary.get("warnings") or ():
        print(f"warning: {warning}")
    link = summary.get("link")
    if link:
        print(f"link: {link['frames_dropped']} frames dropped, {link['frames_lost']} lost, {link['rig_faults']} rig "
              f"faults, {link['reconnects']} reconnects; at most {link['samples_missed_max']} samples missed in a row, "
              f"sample age mean {link['measurement_age_mean_s'] * 1e6:.0f} us, "
              f"max {link['measurement_age_max_s'] * 1e6:.0f} us")
        if "drive_gap_max_s" in link:
            print(f"gaps between DRIVE commands: p50 {link['drive_gap_p50_s'] * 1e3:.2f} ms, p99 "
                  f"{link['drive_gap_p99_s'] * 1e3:.2f} ms, max {link['drive_gap_max_s'] * 1e3:.2f} ms")

            # paced runs only: in lockstep the rig waits for each DRIVE, so no drive is held however long the gap
            if summary.get("realtime") and link["drive_gap_max_s"] > DRIVE_GAP_BUDGET_S:
                print(f"warning: the longest gap between DRIVE commands is beyond the {DRIVE_GAP_BUDGET_S * 1e3:g} ms "
                      "a held drive costs nothing in (docs/hil.md, \"Real time that holds\"): a step under way then "
                      "may have overshot")
    realtime = summary.get("realtime")
    if realtime:
        print(f"real time: {realtime.get('overruns')} overruns in {realtime.get('steps')} steps; step-start jitter "
              f"p50 {realtime.get('jitter_p50_s', 0) * 1e6:.0f} us, "
              f"p99 {realtime.get('jitter_p99_s', 0) * 1e6:.0f} us, "
              f"max {realtime.get('jitter_max_s', 0) * 1e6:.0f} us"
              + (f" (SCHED_FIFO priority {summary['rt_priority']})" if summary.get("rt_priority") else "")
              + (" in the compiled loop" if realtime.get("engine") == "compiled" else ""))
        if (stolen := steal_text(realtime.get("steal"))) is not None:
            print(stolen)
        pauses = realtime.get("gc_pauses")
        if pauses:
            print(f"collector: {pauses['count']} young collections in slack, "
                  f"longest {pauses['max_s'] * 1e6:.0f} us; memory "
                  + ("locked" if realtime.get("memory_locked") else f"not locked ({realtime.get('memory_lock_note')})"))
        if realtime.get("overruns") and not summary.get("rt_priority"):
            print("hint: --rt-priority 50 runs the loop under SCHED_FIFO, so other processes cannot delay it "
                  "(docs/hil.md, \"Real time that holds\")")
