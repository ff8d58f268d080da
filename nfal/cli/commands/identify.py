"""``nfal identify``: identify the rig over its port (K from equilibria, the damping from drive steps); the run is
:func:`nfal.apps.rig_identification.identify_rig`, this module checks the flags and prints."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from nfal.apps.rig_experiments import recorder_capacity
from nfal.apps.rig_identification import IdentifiedRig, IdentifySettings, drive_gap_margin, identify_rig, output_paths
from nfal.cli.commands import COMMANDS
from nfal.cli.commands.common import (add_accept_long_plan, add_rig_options, duration_text, number_list, print_json,
                                      progress_bar, rig_from_args)
from nfal.errors import InvalidParameterError, PlanError, require_duration, require_finite, require_positive
from nfal.hil.link import DRIVE_GAP_BUDGET_S, LONGEST_WAIT_S
from nfal.models.identification import AMPLITUDE_TIME_CONSTANT_S, LONGEST_HOLD_S, IdentificationPlan
from nfal.models.plausibility import MAX_METRES_PER_VOLT, require_plausible
from nfal.models.table2 import WORK_RANGE_M
from nfal.models.transducer import METRES_PER_VOLT

#: The longest --max-silence [s]: the rig's watchdog ramps the drive down after 0.1 s without DRIVE anyway.
LONGEST_SILENCE_S = 10.0
#: The longest plan run without --accept-long-plan [s of typical rig time]: an hour, about 90 times the default plan.
LONG_PLAN_S = 3600.0

DESCRIPTION = """Identify a rig over the nfal rig protocol (a rig, or `nfal rig-emulator` on a pty), automatically:
(1) equilibria: for each height, a closed-loop move with the controller's own law, then the drive it found held
constant until the height has settled (tested on the data); K at each by eq. (16) with |a| = metres_per_volt x V,
and a quartic fit of the form of eq. (17); (2) damping: at each damping height, drive steps of +-step-size
(alternately up and down, each held until settled); each step's response fitted by eq. (13) linearised (stiffness
from the step's own gain, the transducer's amplitude lag included) gives the damping over eq. (6); their geometric
mean and 95 % interval per height. Writes the calibration file (K as `nfal calibrate` writes it, plus "damping",
"equilibria" and "provenance"), the raw samples as CSV next to it (streamed while the experiments run) and a
figure. Give the load's mass (--mass): K by eq. (16) and the stiffness of each step scale with it. Safety: the
drive is clamped to --max-voltage; the rig's watchdog stops it if the host stalls; a landing after lift-off, a
hold that does not settle, a drive that cannot lift the load, a lost link or Ctrl-C stop the experiments, ramp
the drive down and keep every sample on disk."""


def register(commands) -> None:
    identify = commands.add_parser("identify",
                                   help=COMMANDS["identify"].summary,
                                   description=DESCRIPTION,
                                   epilog="Examples: nfal identify --port /tmp/nfal-rig-k2x9 --dry-run; nfal identify "
                                   "--port /tmp/nfal-rig-k2x9 --out rig.json (writes rig.json, rig-raw.csv, rig.png).")
    identify.add_argument("--port", metavar="URL", help="the rig's port: a device, a pty (nfal rig-emulator's first "
                          "line), socket://host:port")
    identify.add_argument("--out", default="rig-calibration.json", metavar="FILE.json",
                          help="the calibration file (default rig-calibration.json); FILE-raw.csv and FILE.png "
                          "beside it")
    identify.add_argument("--overwrite", action="store_true", help="replace FILE.json, FILE-raw.csv and FILE.png of a "
                          "previous identification (refused otherwise)")
    identify.add_argument("--dry-run", action="store_true", help="print the plan and its duration (with --json, as "
                          "JSON); open nothing. A plan that cannot give a result, or a long one, is refused as the run "
                          "would be")
    identify.add_argument("--equilibria", type=number_list, default=np.geomspace(47e-6, 210e-6, 12), metavar="HEIGHTS",
                          help="equilibrium heights [m], A,B,C or START:STOP:COUNT (default 12 heights spaced "
                          "geometrically over 47-210 um, a little beyond the 50-200 um work range)")
    identify.add_argument("--damping-heights", type=number_list, default=np.linspace(*WORK_RANGE_M, 8),
                          metavar="HEIGHTS",
                          help=f"heights of the drive steps [m] (default {WORK_RANGE_M[0]:g}:{WORK_RANGE_M[1]:g}:8)")
    identify.add_argument("--steps", type=int, default=6, metavar="N",
                          help="fitted steps per damping height, even (default 6)")
    identify.add_argument("--step-size", type=float, default=0.03, metavar="FRACTION",
                          help="drive step about the equilibrium drive, relative (default 0.03)")
    identify.add_argument("--max-hold", type=float, default=5.0, metavar="SECONDS",
                          help="a hold not settled by then is a fault (default 5)")
    identify.add_argument("--max-voltage", type=float, default=100.0, metavar="V",
                          help="the drive never exceeds this (default 100; the rig's own limit applies too)")
    identify.add_argument("--metres-per-volt", type=float, default=METRES_PER_VOLT, metavar="M/V",
                          help="|a| per volt at resonance, as the Controller's metres_per_volt (default %(default)s)")
    identify.add_argument("--amplitude-time-constant", type=float, metavar="SECONDS",
                          help="the transducer's amplitude lag 2Q/omega_r in the step fits "
                          "(default 5.58e-3: Q 500 at 28.5 kHz)")
    identify.add_argument("--connect-timeout", type=float, default=2.0, metavar="SECONDS", help="wait for the rig's "
                          f"HELLO_ACK (default 2, at most {LONGEST_WAIT_S:g})")
    identify.add_argument("--max-silence", type=float, default=0.5, metavar="SECONDS", help="no measurement for this "
                          f"long is a lost link (default 0.5, at most {LONGEST_SILENCE_S:g})")
    identify.add_argument("--json", action="store_true", help="print the summary (with --dry-run, the plan) as JSON")
    add_accept_long_plan(identify, f"{duration_text(LONG_PLAN_S)} of rig time (its typical duration, as --dry-run "
                         "prints it)")
    add_rig_options(identify)
    identify.set_defaults(handler=run_identify)


#: The plan's fields and the flags that set them (its errors name the flag).
PLAN_FLAGS = {"equilibrium_heights_m": "--equilibria", "damping_heights_m": "--damping-heights",
              "step_fraction": "--step-size", "steps": "--steps", "max_hold_s": "--max-hold"}


def _plan(args: argparse.Namespace):
    try:
        return IdentificationPlan(tuple(np.sort(args.equilibria)), tuple(np.sort(args.damping_heights)[::-1]),
                                  step_fraction=args.step_size, steps=args.steps, max_hold_s=args.max_hold)
    except InvalidParameterError as exc:
        raise InvalidParameterError(PLAN_FLAGS.get(exc.name, exc.name), exc.value, exc.allowed) from None


def _check_length(plan, accepted: bool) -> None:
    typical, longest = plan.duration_s()
    if typical > LONG_PLAN_S and not accepted:
        raise PlanError(f"the plan takes about {duration_text(typical)} of rig time (up to {duration_text(longest)}), "
                        f"more than {duration_text(LONG_PLAN_S)}: give --accept-long-plan to run it, or fewer "
                        "--equilibria, --damping-heights or --steps")


def _print_plan(plan, as_json: bool) -> None:
    typical, longest = plan.duration_s()
    if as_json:
        print_json({"equilibrium_heights_m": plan.equilibrium_heights_m, "damping_heights_m": plan.damping_heights_m,
                    "steps": plan.steps, "step_fraction": plan.step_fraction, "settle_window_s": plan.settle_window_s,
                    "settle_drift": plan.settle_drift, "max_hold_s": plan.max_hold_s, "holds": plan.holds(),
                    "moves": plan.moves(), "duration_s": {"typical": typical, "longest": longest}})
        return
    print(f"equilibria: {len(plan.equilibrium_heights_m)} heights "
          f"{', '.join(f'{h * 1e6:.0f}' for h in plan.equilibrium_heights_m)} um: closed-loop move, "
          f"then the drive held until settled ({plan.settle_window_s:g} s window, "
          f"drift < {plan.settle_drift * 100:g} %)")
    print(f"damping: {len(plan.damping_heights_m)} heights "
          f"{', '.join(f'{h * 1e6:.0f}' for h in plan.damping_heights_m)} um: "
          f"move, then {plan.steps} drive steps of +-{plan.step_fraction * 100:g} % each held until settled")
    print(f"duration: about {typical:.0f} s of rig time (at most {longest:.0f} s if every hold ran to its limit)")


def run_identify(args: argparse.Namespace) -> int:
    require_duration("--max-hold", args.max_hold, LONGEST_HOLD_S)  # named by its flag, before the plan checks it
    plan = _plan(args)
    for name in ("metres_per_volt", "max_voltage"):
        require_positive(f"--{name.replace('_', '-')}", getattr(args, name))
    require_duration("--connect-timeout", args.connect_timeout, LONGEST_WAIT_S)
    require_duration("--max-silence", args.max_silence, LONGEST_SILENCE_S)
    require_plausible("--metres-per-volt", args.metres_per_volt, MAX_METRES_PER_VOLT, "m/V")
    rig, out = rig_from_args(args), Path(args.out)  # every number checked before --dry-run says the plan is fine
    lag = AMPLITUDE_TIME_CONSTANT_S if args.amplitude_time_constant is None else args.amplitude_time_constant
    if not require_finite("--amplitude-time-constant", lag, "a time >= 0 s") >= 0:
        raise InvalidParameterError("--amplitude-time-constant", lag, "a time >= 0 s")
    if out.suffix.lower() != ".json":
        raise InvalidParameterError("--out", args.out, "a calibration file name ending in .json")
    _check_length(plan, args.accept_long_plan)
    recorder_capacity(plan)  # a plan whose samples cannot be held is refused, even accepted, and by --dry-run
    if args.dry_run:
        _print_plan(plan, args.json)
        return 0
    if not args.port:
        raise InvalidParameterError("--port", args.port, "the rig's port URL (or --dry-run)")
    previous = [path.name for path in output_paths(out) if path.exists()]
    if previous and not args.overwrite:  # a previous identification's measurements are not ours to replace
        raise InvalidParameterError("--out", args.out, f"a name of no previous identification ({', '.join(previous)} "
                                    "exist); give another --out, or --overwrite to replace them")
    settings = IdentifySettings(args.port, out, rig, metres_per_volt=args.metres_per_volt, max_voltage=args.max_voltage,
                                lag_s=lag, connect_timeout_s=args.connect_timeout, max_silence_s=args.max_silence)
    with progress_bar(plan.holds(), "identify") as bar:
        identified = identify_rig(plan, settings, on_hold=lambda: bar.update(1))
    _report(identified, args.json)
    return 0


def _report(identified: IdentifiedRig, as_json: bool) -> None:
    table, timing = identified.result.damping, identified.timing
    summary = {"calibration": str(identified.calibration), "raw_data": str(identified.raw),
               "figure": str(identified.figure), "rig_time_s": identified.rig_time_s, "samples": identified.samples,
               "K": identified.result.calibration.report(), "damping": table.to_dict(), "realtime": timing}
    if as_json:
        print_json(summary)
        return
    report = summary["K"]
    print(f"identified in {identified.rig_time_s:.1f} s of rig time ({identified.samples} samples): "
          f"{identified.calibration}, {identified.raw}, {identified.figure}")
    print(f"real time: {drive_gap_margin(timing)} (the rig's watchdog: {timing['rig_watchdog_s'] * 1e3:g} ms)")
    if timing["drive_gaps"]["max_s"] > DRIVE_GAP_BUDGET_S:
        print(f"warning: the longest gap between DRIVE commands, {timing['drive_gaps']['max_s'] * 1e3:.1f} ms, is "
              f"beyond the {DRIVE_GAP_BUDGET_S * 1e3:g} ms a held drive costs nothing in (docs/hil.md, \"Real time "
              "that holds\"): the machine paused the host; a step that was under way then may have overshot")
    print(f"K(sigma) from {len(identified.result.equilibria)} equilibria (eq. 16), quartic as eq. (17): coefficients "
          f"{', '.join(f'{c:.6g}' for c in report['coefficients'])}; residual rms {report['residual_rms']:.3g}")
    print("damping over eq. (6), mean and 95 % interval:")
    for h, f, low, high in zip(table.heights_m, table.factors, table.factors_low, table.factors_high):
        print(f"  {h * 1e6:6.1f} um: {f:7.3f}  [{low:.3f}, {high:.3f}]")
