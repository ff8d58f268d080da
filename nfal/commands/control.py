"""``nfal design`` (gain schedule and the Fig. 8 map) and ``nfal compare`` (Figs. 9-10 in simulation)."""

from __future__ import annotations

import argparse
import time

import numpy as np

from nfal.commands.common import (add_output_options, add_rig_options, finite_float, number_list, print_json, print_step_table,
                                  progress_bar, rig_from_args)
from nfal.models.errors import InvalidParameterError

DISCRETISATION_CHOICES = {"forward-euler": "forward_euler", "zoh": "zoh"}
PLACEMENTS = ("continuous", "sampled")
GAIN_UNITS = {"height_m": "m", "kp": "m/m", "ki": "1/s", "kd": "s", "slow_pole_hz": "Hz", "fast_pole_hz": "Hz"}


def register(commands) -> None:
    design = commands.add_parser(
        "design", help="gain-scheduled PID over the work range and its stability map (Sec. 4.1, Fig. 8)",
        description="Design the PID of eqs. (21)-(22) at every height (two double pole pairs, -3 dB bandwidth of the "
        "closed loop = the closed-loop cut-off, derivative filter at the filter cut-off), for the loop sampled at "
        "--sample-rate (default) or the continuous one of eqs. (23)-(24) (--placement continuous, the paper), and "
        "compute the Fig. 8 map: max |z| of the local discrete loop for every (design height, operating height). "
        "The paper's Fig. 8: --placement continuous (forward-Euler map). With --calibration, K(sigma) and the "
        "damping correction of an identified rig enter eq. (20). Gains in SI: kp [m/m], ki [1/s], kd [s].")
    design.add_argument("--heights", type=number_list, default=number_list("50e-6:200e-6:31"),
                        help="design and operating heights [m]: A,B,C or START:STOP:COUNT (default 50e-6:200e-6:31)")
    design.add_argument("--discretisation", choices=tuple(DISCRETISATION_CHOICES),
                        help="map's discrete loop: forward-euler (the paper's Fig. 8) or zoh (exact plant, "
                        "forward-Euler controller: what the digital loop realises) (default: forward-euler for "
                        "--placement continuous, zoh for sampled)")
    _add_design_options(design)
    add_output_options(design)
    design.set_defaults(handler=run_design)

    compare = commands.add_parser(
        "compare", help="gain-scheduled vs. linear controllers on a staircase reference (Figs. 9-10)",
        description="Simulate the sampled closed loop (simplified plant eq. (13), coloured sensor noise, the "
        "discrete PID with saturation and anti-windup) for each controller on the same reference and noise, "
        "and report per step: rise time (10-90 %%), overshoot, 2 %% settling time, steady-state noise RMS, IAE.")
    compare.add_argument("--controllers", default="gs,80,120,160",
                         help="'gs' and/or design heights of linear controllers in um (default gs,80,120,160)")
    compare.add_argument("--seed", type=int, default=0, help="seed of the measurement noise (default 0)")
    compare.add_argument("--noise-peak", type=finite_float, default=2e-6, help="peak noise magnitude [m] (default 2e-6; 0: none)")
    compare.add_argument("--noise-cutoff", type=finite_float, default=300.0, help="noise colouring cut-off [Hz] (default 300)")
    compare.add_argument("--levels", type=number_list, default=number_list("60e-6,100e-6,140e-6,180e-6,140e-6,100e-6,60e-6"),
                         help="reference levels [m] (default 60,100,140,180,140,100,60 um)")
    compare.add_argument("--hold", type=finite_float, default=0.6, help="hold time of each level [s] (default 0.6)")
    compare.add_argument("--max-excitation", type=finite_float, default=10e-6, help="actuator limit |a|max [m] (default 10e-6)")
    compare.add_argument("--full-schedule", action="store_true",
                         help="with --placement continuous: schedule the paper's designs at every height, even those "
                         "the 2 kHz forward-Euler loop cannot realise (default: hold the gains below the lowest "
                         "realisable height; the sampled placement realises all)")
    _add_design_options(compare)
    add_output_options(compare)
    compare.set_defaults(handler=run_compare)


def _add_design_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--closed-loop-cutoff", type=finite_float, default=10.0, help="closed-loop -3 dB bandwidth [Hz] (default 10)")
    parser.add_argument("--filter-cutoff", type=finite_float, default=300.0, help="derivative filter cut-off [Hz] (default 300)")
    parser.add_argument("--sample-rate", type=finite_float, default=2000.0, help="controller sampling rate [Hz] (default 2000)")
    parser.add_argument("--placement", choices=PLACEMENTS, default="sampled",
                        help="loop whose poles are placed: sampled (the loop the discrete law realises at --sample-rate: "
                        "ZOH plant, forward-Euler integrator and derivative filter; the Controller FMU's default) or "
                        "continuous (eqs. 23-24, the paper's Fig. 8) (default sampled)")
    parser.add_argument("--calibration", metavar="FILE.json",
                        help="calibration file: K(sigma) and, from nfal identify, the damping correction of eq. (6) "
                        "for the plant and the design (default: eq. (17), eq. (6) as it is)")
    add_rig_options(parser)


def _model(args: argparse.Namespace):
    """(rig, RigCalibration, DesignSpec) of the design options."""
    from nfal.models.calibration import RigCalibration, load_rig_calibration, paper_calibration
    from nfal.models.pid_design import DesignSpec

    rig = rig_from_args(args)
    model = load_rig_calibration(args.calibration, rig) if args.calibration else RigCalibration(paper_calibration())
    sample_rate = args.sample_rate if args.placement == "sampled" else None
    return rig, model, DesignSpec(args.closed_loop_cutoff, args.filter_cutoff, sample_rate)


def run_design(args: argparse.Namespace) -> int:
    from nfal.models.pid_design import design_schedule
    from nfal.models.stability import realizable_schedule, stability_map

    rig, model, spec = _model(args)
    heights = np.unique(args.heights)
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
        from nfal.figures.control import plot_stability_map

        plot_stability_map(args.plot, grid)
    if args.json:
        print_json(result)
        return 0
    print(f"{'height [um]':>11} {'kp [m/m]':>11} {'ki [1/s]':>10} {'kd [s]':>11} {'p1 [Hz]':>8} {'p2 [Hz]':>8} {'diag |z|':>9}")
    for i, d in enumerate(designs):
        print(f"{d.height_m * 1e6:11.1f} {d.kp_si:11.4g} {d.ki_si:10.4g} {d.kd_si:11.4g} {d.slow_pole_hz:8.2f} "
              f"{d.fast_pole_hz:8.1f} {grid.max_pole_modulus[i, i]:9.4f}")
    print(f"map ({args.placement} placement, {discretisation}, {args.sample_rate:g} Hz): max |z| from {grid.max_pole_modulus.min():.4f} "
          f"to {grid.max_pole_modulus.max():.4f}")
    if realizable_from is not None:
        print(f"{discretisation} loop stable on the diagonal from {realizable_from * 1e6:.1f} um up")
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
    from nfal.models.closed_loop import Staircase, simulate_closed_loop
    from nfal.models.control_law import DiscreteControlLaw
    from nfal.models.measurement_noise import coloured_noise
    from nfal.models.pid_design import design_schedule, fixed_design
    from nfal.models.plant import SimplifiedPlant
    from nfal.models.stability import realizable_schedule
    from nfal.models.step_metrics import step_metrics, total_iae
    from nfal.orchestration.run import MAX_STEPS

    keys = _parse_controllers(args.controllers)
    started = time.perf_counter()
    reference = Staircase(tuple(args.levels), hold_s=args.hold)
    samples = reference.duration_s * args.sample_rate
    if samples > MAX_STEPS:  # a mistyped --hold would allocate terabytes
        raise InvalidParameterError("--hold", args.hold, f"a staircase of at most {MAX_STEPS:,} samples at "
                                    f"{args.sample_rate:g} Hz, not {samples:,.0f}")
    rig, model, spec = _model(args)
    plant = SimplifiedPlant(rig, model.calibration, excess_damping=model.damping)
    noise = coloured_noise(reference.samples(args.sample_rate), sample_rate_hz=args.sample_rate,
                           cutoff_hz=args.noise_cutoff, peak_m=args.noise_peak, seed=args.seed)
    work_range = (min(reference.levels_m), max(reference.levels_m))
    results, runs = {}, {}
    with progress_bar(len(keys), "closed-loop runs") as bar:
        for key in keys:
            if key == "gs":
                gains = design_schedule(None, rig, model.calibration, spec, damping=model.damping)
                if not args.full_schedule:
                    gains = realizable_schedule(gains, rig, sample_rate_hz=args.sample_rate,
                                                discretisation="zoh" if spec.sample_rate_hz else "forward_euler")
            else:
                gains = fixed_design(float(key) * 1e-6, rig, model.calibration, spec, damping=model.damping)
            law = DiscreteControlLaw(gains, sample_rate_hz=args.sample_rate, max_excitation_m=args.max_excitation,
                                     reference_range_m=work_range)
            run = simulate_closed_loop(law, plant, reference, noise)
            runs[key] = run
            results[key] = {"name": law.name, "iae": total_iae(run),
                            "steps": [m.to_dict() for m in step_metrics(run, reference)]}
            bar.update()
    output = {"controllers": results,
              "reference": {"levels_m": list(reference.levels_m), "hold_s": reference.hold_s, "lead_s": reference.lead_s},
              "noise": {"peak_m": args.noise_peak, "cutoff_hz": args.noise_cutoff, "seed": args.seed},
              "sample_rate_hz": args.sample_rate, "max_excitation_m": args.max_excitation,
              "runtime_s": time.perf_counter() - started}
    if args.plot:
        from nfal.figures.control import plot_comparison

        plot_comparison(args.plot, runs)
    if args.json:
        print_json(output)
        return 0
    _print_table(results)
    return 0


def _print_table(results: dict) -> None:
    for key, result in results.items():
        print(f"{key} ({result['name']}): IAE {result['iae'] * 1e6:.3f} um s")
        print_step_table(result["steps"])
