"""``nfal design`` (gain schedule and the Fig. 8 map) and ``nfal compare`` (Figs. 9-10 in simulation)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from nfal.apps.fig7 import HARDWARE_LEAD_S
from nfal.apps.rig_comparison import compare_on_rig
from nfal.cli.commands import COMMANDS
from nfal.cli.commands.common import (add_output_options, add_rig_options, fill_defaults, finite_float, number_list,
                                      print_json, print_step_table, progress_bar, refuse_given, rig_from_args)
from nfal.cli.commands.cosim import parse_parameter
from nfal.errors import InvalidParameterError, optional_positive
from nfal.fmus.rig_contract import rig_parameter_values
from nfal.models.calibration import RigCalibration, load_rig_calibration, paper_calibration
from nfal.models.reference import Staircase
from nfal.models.comparison import simulate_comparison
from nfal.models.pid_design import DesignSpec, design_schedule
from nfal.models.plausibility import require_clearances
from nfal.models.stability import realizable_schedule, stability_map
from nfal.models.step_metrics import step_metrics, total_iae
from nfal.models.table2 import (
    CLOSED_LOOP_CUTOFF_HZ,
    FILTER_CUTOFF_HZ,
    MAX_EXCITATION_M,
    NOISE_CUTOFF_HZ,
    NOISE_PEAK_M,
    REFERENCE_ZERO_RATIO,
    SAMPLING_RATE_HZ,
    STAIRCASE_LEVELS_M,
    WORK_RANGE_M,
)
from nfal.orchestration.run import MAX_STEPS

DISCRETISATION_CHOICES = {"forward-euler": "forward_euler", "zoh": "zoh"}
PLACEMENTS = ("continuous", "sampled")
GAIN_UNITS = {"height_m": "m", "kp": "m/m", "ki": "1/s", "kd": "s", "slow_pole_hz": "Hz", "fast_pole_hz": "Hz"}
#: The simulated noise's options and their defaults (None in the parser: with --port they are refused, not ignored).
NOISE_DEFAULTS = {"seed": 0, "noise_peak": NOISE_PEAK_M, "noise_cutoff": NOISE_CUTOFF_HZ}


def register(commands) -> None:
    design = commands.add_parser(
        "design", help=COMMANDS["design"].summary,
        description="Design the PID of eqs. (21)-(22) at every height (two double pole pairs, -3 dB bandwidth of the "
        "closed loop = the closed-loop cut-off, derivative filter at the filter cut-off), for the loop sampled at "
        "--sample-rate (default) or the continuous one of eqs. (23)-(24) (--placement continuous, the paper), and "
        "compute the Fig. 8 map: max |z| of the local discrete loop for every (design height, operating height). "
        "The paper's Fig. 8: --placement continuous (forward-Euler map). With --calibration, K(sigma) and the "
        "damping correction of an identified rig enter eq. (20). Gains in SI: kp [m/m], ki [1/s], kd [s].")
    design.add_argument("--heights", type=number_list, default=np.linspace(*WORK_RANGE_M, 31),
                        help="design and operating heights [m]: A,B,C or START:STOP:COUNT (default "
                        f"{WORK_RANGE_M[0]:g}:{WORK_RANGE_M[1]:g}:31)")
    design.add_argument("--discretisation", choices=tuple(DISCRETISATION_CHOICES),
                        help="map's discrete loop: forward-euler (the paper's Fig. 8) or zoh (exact plant, "
                        "forward-Euler controller: what the digital loop realises) (default: forward-euler for "
                        "--placement continuous, zoh for sampled)")
    _add_design_options(design)
    add_output_options(design)
    design.set_defaults(handler=run_design)

    compare = commands.add_parser(
        "compare", help=COMMANDS["compare"].summary,
        description="Simulate the sampled closed loop (simplified plant eq. (13), coloured sensor noise, the "
        "discrete PID with saturation and anti-windup) for each controller on the same reference and noise, "
        "and report per step: rise time (10-90 %), overshoot, 2 % settling time, steady-state noise RMS, IAE. "
        "With --port, run each controller on the rig instead (Figs. 11-12): the hardware-in-the-loop structure "
        "fig7_hil, paced in real time, one run per controller from rest (a 1 s first level for the lift-off); "
        "the rig's own sensor gives the noise, and every run's results.csv is kept under --runs-dir.")
    compare.add_argument("--controllers", default="gs,80,120,160", metavar="LIST",
                         help="'gs' and/or linear controllers named by their design height in um, as the paper names "
                         "them (80: the design at 80e-6 m; default gs,80,120,160)")
    compare.add_argument("--seed", type=int, metavar="N",
                         help="seed of the measurement noise (default 0; not with --port)")
    compare.add_argument("--noise-peak", type=finite_float, metavar="m",
                         help=f"peak noise magnitude [m] (default {NOISE_PEAK_M:g}; 0: none; not with --port)")
    compare.add_argument("--noise-cutoff", type=finite_float, metavar="Hz",
                         help=f"noise colouring cut-off [Hz] (default {NOISE_CUTOFF_HZ:g}; not with --port)")
    compare.add_argument("--levels", type=number_list, default=list(STAIRCASE_LEVELS_M), metavar="m,m,...",
                         help="reference levels [m] (default 60e-6,100e-6,140e-6,180e-6,140e-6,100e-6,60e-6)")
    compare.add_argument("--hold", type=finite_float, default=0.6, metavar="s",
                         help="hold time of each level [s] (default 0.6)")
    compare.add_argument("--max-excitation", type=finite_float, default=MAX_EXCITATION_M, metavar="m",
                         help="actuator limit |a|max [m] (default %(default)s)")
    compare.add_argument("--full-schedule", action="store_true",
                         help="with --placement continuous only: schedule the paper's designs at every height, even "
                         "those the 2 kHz forward-Euler loop cannot realise (default: hold the gains below the lowest "
                         "realisable height; the sampled placement realises all)")
    compare.add_argument("--port", metavar="URL", help="run on the rig at URL (a device, a pty of nfal rig-emulator, "
                         "socket://host:port) instead of simulating; the noise is then the rig's own (--noise-* and "
                         "--seed are refused)")
    compare.add_argument("--runs-dir", metavar="DIR", help="with --port only: where each run's folder goes (default "
                         "runs/compare-<date-time>)")
    compare.add_argument("--build-dir", metavar="DIR", help="with --port only: where fig7_hil.ssp is built "
                         "(default build)")
    compare.add_argument("--param", action="append", default=[], metavar="ELEMENT.VAR=VALUE",
                         help="with --port only: set a parameter of fig7_hil in every run (repeatable), e.g. "
                         "proxy.max_missed_samples=100")
    _add_design_options(compare)
    add_output_options(compare)
    compare.set_defaults(handler=run_compare)


def _add_design_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--closed-loop-cutoff", type=finite_float, default=CLOSED_LOOP_CUTOFF_HZ, metavar="Hz",
                        help="closed-loop -3 dB bandwidth [Hz] (default %(default)s)")
    parser.add_argument("--filter-cutoff", type=finite_float, default=FILTER_CUTOFF_HZ, metavar="Hz",
                        help="derivative filter cut-off [Hz] (default %(default)s)")
    parser.add_argument("--sample-rate", type=finite_float, default=SAMPLING_RATE_HZ, metavar="Hz",
                        help="controller sampling rate [Hz] (default %(default)s)")
    parser.add_argument("--placement", choices=PLACEMENTS, default="sampled",
                        help="loop whose poles are placed: sampled (the loop the discrete law realises at "
                        "--sample-rate: ZOH plant, forward-Euler integrator and derivative filter; the Controller "
                        "FMU's default) or continuous (eqs. 23-24, the paper's Fig. 8) (default sampled)")
    parser.add_argument("--reference-zero", type=finite_float, default=REFERENCE_ZERO_RATIO, metavar="RHO",
                        help="the law's reference zero, in slow-pole time constants: the reference passes through a "
                        "filter that cancels the PI zero (less overshoot), and the sampled placement reaches its "
                        "cut-off through it; the Controller FMU's reference_zero (default %(default)s; 0: off, the "
                        "paper's law)")
    parser.add_argument("--calibration", metavar="FILE.json",
                        help="calibration file: K(sigma) and, from nfal identify, the damping correction of eq. (6) "
                        "for the plant and the design (default: eq. (17), eq. (6) as it is)")
    add_rig_options(parser)


def _model(args: argparse.Namespace):
    """(rig, RigCalibration, DesignSpec) of the design options."""

    rig = rig_from_args(args)
    model = load_rig_calibration(args.calibration, rig) if args.calibration else RigCalibration(paper_calibration())
    sample_rate = args.sample_rate if args.placement == "sampled" else None
    reference_zero = optional_positive("--reference-zero", args.reference_zero)
    return rig, model, DesignSpec(args.closed_loop_cutoff, args.filter_cutoff, sample_rate, reference_zero)


def run_design(args: argparse.Namespace) -> int:
    rig, model, spec = _model(args)
    heights = np.unique(require_clearances("--heights", args.heights))
    schedule = design_schedule(heights, rig, model.calibration, spec, damping=model.damping)
    default = "forward-euler" if spec.sample_rate_hz is None else "zoh"
    discretisation = DISCRETISATION_CHOICES[args.discretisation or default]
    grid = stability_map(heights, heights, rig, model.calibration, spec, sample_rate_hz=args.sample_rate,
                         discretisation=discretisation, damping=model.damping)
    try:
        realizable_from = realizable_schedule(schedule, rig, sample_rate_hz=args.sample_rate,
                                             discretisation=discretisation).height_range_m[0]
    except ValueError:
        realizable_from = None
    designs = schedule.designs
    result = {
        "height_m": heights,
        "kp": [d.kp_si for d in designs], "ki": [d.ki_si for d in designs], "kd": [d.kd_si for d in designs],
        "slow_pole_hz": [d.slow_pole_hz for d in designs], "fast_pole_hz": [d.fast_pole_hz for d in designs],
        "units": GAIN_UNITS,
        "placement": args.placement,
        "stability_map": {**grid.to_dict(), "discretisation": discretisation, "sample_rate_hz": args.sample_rate},
        "realizable_from_m": realizable_from,
    }
    if args.plot:
        # matplotlib only when plotting
        from nfal.apps.figures.control import plot_stability_map

        plot_stability_map(args.plot, grid)
    if args.json:
        print_json(result)
        return 0
    print(f"{'height [um]':>11} {'kp [m/m]':>11} {'ki [1/s]':>10} {'kd [s]':>11} {'p1 [Hz]':>8} {'p2 [Hz]':>8} "
          f"{'diag |z|':>9}")
    for i, d in enumerate(designs):
        print(f"{d.height_m * 1e6:11.1f} {d.kp_si:11.4g} {d.ki_si:10.4g} {d.kd_si:11.4g} {d.slow_pole_hz:8.2f} "
              f"{d.fast_pole_hz:8.1f} {grid.max_pole_modulus[i, i]:9.4f}")
    print(f"map ({args.placement} placement, {discretisation}, {args.sample_rate:g} Hz): max |z| from "
          f"{grid.max_pole_modulus.min():.4f} to {grid.max_pole_modulus.max():.4f}")
    if realizable_from is not None:
        held = (f"; below, the Controller (realizable_only, its default) holds the gains of "
                f"{realizable_from * 1e6:.1f} um" if realizable_from > heights[0] else "")
        print(f"{discretisation} loop stable on the diagonal from {realizable_from * 1e6:.1f} um up{held}")
    return 0


def _parse_controllers(text: str) -> list[str]:
    keys = []
    for item in (part.strip() for part in text.split(",")):
        if item == "gs":
            keys.append("gs")
            continue
        try:
            value = float(item)
        except ValueError:
            raise InvalidParameterError("--controllers", item, "'gs' or a design height in um") from None
        keys.append(f"{value:g}")
    if not keys or len(set(keys)) != len(keys):
        raise InvalidParameterError("--controllers", text, "distinct controllers, e.g. gs,80,120,160")
    return keys


def run_compare(args: argparse.Namespace) -> int:
    keys = _parse_controllers(args.controllers)
    _refuse_unused(args)
    started = time.perf_counter()
    require_clearances("--levels", args.levels)  # 60 for 60 um: refused with the unit hint
    # from rest on a rig: a 1 s first level for the lift-off
    reference = Staircase(tuple(args.levels), hold_s=args.hold, **({"lead_s": HARDWARE_LEAD_S} if args.port else {}))
    samples = reference.duration_s * args.sample_rate
    if samples > MAX_STEPS:  # a mistyped --hold would allocate terabytes
        raise InvalidParameterError("--hold", args.hold, f"a staircase of at most {MAX_STEPS:,} samples at "
                                    f"{args.sample_rate:g} Hz, not {samples:,.0f}")
    if args.port:
        runs = _rig_runs(args, keys, reference)
        source = {"rig": args.port}
    else:
        runs = _simulated_runs(args, keys, reference)
        source = {"noise": {"peak_m": args.noise_peak, "cutoff_hz": args.noise_cutoff, "seed": args.seed}}
    results = {key: _run_metrics(run, reference) for key, run in runs.items()}
    output = {"controllers": results,
              "reference": {"levels_m": list(reference.levels_m), "hold_s": reference.hold_s,
                            "lead_s": reference.lead_s},
              **source, "sample_rate_hz": args.sample_rate, "max_excitation_m": args.max_excitation,
              "runtime_s": time.perf_counter() - started}
    if args.plot:
        # matplotlib only when plotting
        from nfal.apps.figures.control import plot_comparison

        plot_comparison(args.plot, runs)
    if args.json:
        print_json(output)
        return 0
    _print_table(results)
    return 0


def _refuse_unused(args: argparse.Namespace) -> None:
    """Each option that would have no effect in the mode chosen is refused, naming the option it needs."""
    if args.port:
        refuse_given({f"--{dest.replace('_', '-')}": getattr(args, dest) for dest in NOISE_DEFAULTS},
                     "with --port (the rig's own sensor gives the noise)")
    else:
        refuse_given({"--runs-dir": args.runs_dir, "--build-dir": args.build_dir, "--param": args.param},
                     "without --port (it is for the runs on the rig; a simulated comparison keeps no runs)")
        fill_defaults(args, NOISE_DEFAULTS)
    if args.placement != "continuous":
        refuse_given({"--full-schedule": args.full_schedule},
                     "without --placement continuous (the sampled placement realises every design)")


def _run_metrics(run, reference) -> dict:
    return {"name": run.controller, "iae": total_iae(run), "steps": [m.to_dict() for m in step_metrics(run, reference)]}


def _simulated_runs(args: argparse.Namespace, keys: list[str], reference) -> dict:
    """Each controller against the simplified plant (with the calibration's damping), same noise: key -> run."""

    rig, model, spec = _model(args)
    with progress_bar(len(keys), "closed-loop runs") as bar:
        return simulate_comparison(keys, rig, model.calibration, spec, reference, sample_rate_hz=args.sample_rate,
                                   max_excitation_m=args.max_excitation, noise_peak_m=args.noise_peak,
                                   noise_cutoff_hz=args.noise_cutoff, seed=args.seed, damping=model.damping,
                                   full_schedule=args.full_schedule, progress=bar.update)


def _rig_runs(args: argparse.Namespace, keys: list[str], reference) -> dict:
    """Each controller on the rig at ``args.port`` (fig7_hil, real time, from rest): key -> run."""
    parameters = {"proxy.port": args.port, "Controller.placement": args.placement,
                  "Controller.closed_loop_cutoff": args.closed_loop_cutoff,
                  "Controller.filter_cutoff": args.filter_cutoff, "Controller.max_excitation": args.max_excitation,
                  "Controller.realizable_only": not args.full_schedule,
                  "Controller.reference_zero": args.reference_zero,
                  "Controller.reference_min": min(reference.levels_m),
                  "Controller.reference_max": max(reference.levels_m),
                  **({"Controller.calibration": str(Path(args.calibration).resolve())} if args.calibration else {}),
                  **_rig_parameters(args), **dict(parse_parameter(text) for text in args.param)}
    with progress_bar(len(keys), "runs on the rig") as bar:
        runs, folder = compare_on_rig(keys, reference, parameters, sample_rate_hz=args.sample_rate,
                                      build_dir=args.build_dir, runs_dir=args.runs_dir, progress=bar.update)
    print(f"nfal compare: the runs on the rig are in {folder}", file=sys.stderr)
    return runs


def _rig_parameters(args: argparse.Namespace) -> dict:
    """The rig options (``--mass`` ...) as the Controller's parameters (its design model)."""

    return {f"Controller.{name}": value for name, value in rig_parameter_values(rig_from_args(args)).items()}


def _print_table(results: dict) -> None:
    for key, result in results.items():
        print(f"{key} ({result['name']}): IAE {result['iae'] * 1e6:.3f} um s")
        print_step_table(result["steps"])
