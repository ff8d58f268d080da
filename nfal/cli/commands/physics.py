"""``nfal calibrate`` (numerical, experimental) and ``nfal validate table1``."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from nfal.cli.commands import COMMANDS
from nfal.cli.commands.common import (add_output_options, add_rig_options, finite_float, number_list, output_file,
                                      print_json, progress_bar, rig_from_args)
from nfal.errors import InvalidParameterError
from nfal.models.calibration import TabulatedK, paper_calibration, perturbation_calibration
from nfal.models.excitation import paper_shape, parse_shape
from nfal.models.measured_calibration import EquilibriumData, VoltageAmplitudeMap, fit_calibration
from nfal.models.perturbation import DEFAULT_NODES, perturbation_K
from nfal.models.reynolds import time_marching_K
from nfal.models.table1 import TABLE1, run_case

SHAPE_HELP = ("excitation form: piston, plate:N (free circular plate, N nodal circles), paper (Fig. 3 stand-in) or a "
              "CSV of R,eps_hat")


def register(commands) -> None:
    calibrate = commands.add_parser("calibrate", help=COMMANDS["calibrate"].summary,
                                    description="Find K(sigma) of eq. (12), numerically from an excitation form "
                                    "or from measured equilibria (Sec. 3.2).")
    kinds = calibrate.add_subparsers(dest="kind", metavar="KIND", required=True)

    numerical = kinds.add_parser(
        "numerical", help="K(sigma) from Reynolds' equation for an excitation form (Sec. 3.2.1)",
        description="K(sigma) from Reynolds' equation for a fixed object. 'perturbation' solves eqs. (9)-(12) "
        "(exact as delta -> 0, milliseconds); 'time-marching' integrates eq. (3) at finite delta to periodic "
        "steady state (the paper's route, the cross-check). Prints JSON {sigma, K} with --json.")
    numerical.add_argument("--shape", default="paper", help=SHAPE_HELP + " (default: paper)")
    numerical.add_argument("--method", choices=("perturbation", "time-marching"), default="perturbation",
                           help="solution route (default: perturbation)")
    numerical.add_argument("--sigma", type=number_list, default=number_list("5:500:100"),
                           help="squeeze numbers: A,B,C or START:STOP:COUNT (default 5:500:100)")
    numerical.add_argument("--delta", type=finite_float, default=0.01,
                           help="excitation norm delta for time-marching (default 0.01)")
    numerical.add_argument("--nodes", type=int, help="radial nodes (default 401 perturbation, 101 time-marching)")
    numerical.add_argument("--steps-per-period", type=int, default=256,
                           help="time steps per excitation period (time-marching)")
    numerical.add_argument("--out", metavar="FILE.json", type=output_file(".json"),
                           help="write the result as a calibration file for the plant")
    add_output_options(numerical)
    numerical.set_defaults(handler=calibrate_numerical)

    experimental = kinds.add_parser(
        "experimental", help="K(sigma) from measured equilibria (Sec. 3.2.2, eqs. 16-18)",
        description="K at each measured equilibrium by eq. (16), or (18) with a magnetic force column, and a "
        "least-squares polynomial of the form of eq. (17). DATA.csv has columns height_m and excitation_m "
        "(or voltage_v with --metres-per-volt or --voltage-map), optionally magnetic_force_n (downward, N).")
    experimental.add_argument("data", metavar="DATA.csv", help="measured equilibria")
    experimental.add_argument("--degree", type=int, default=4, help="polynomial degree (default 4, as eq. 17)")
    voltage = experimental.add_mutually_exclusive_group()
    voltage.add_argument("--metres-per-volt", type=finite_float,
                         help="linear map |a| = gain * V for voltage_v data [m/V]")
    voltage.add_argument("--voltage-map", metavar="MAP.csv",
                         help="measured (voltage_v, amplitude_m) table for voltage_v data")
    experimental.add_argument("--out", metavar="FILE.json", type=output_file(".json"),
                              help="write the fitted calibration file for the plant")
    add_rig_options(experimental)
    add_output_options(experimental)
    experimental.set_defaults(handler=calibrate_experimental)

    validate = commands.add_parser("validate", help=COMMANDS["validate"].summary,
                                   description="Reproduce the paper's validation results.")
    checks = validate.add_subparsers(dest="check", metavar="CHECK", required=True)
    table1 = checks.add_parser(
        "table1", help="Table 1 / Fig. 5: simplified model vs. full Reynolds model",
        description="The four cases of Table 1 (paper's Fig. 3 form, no magnets): the object is released from "
        "rest and both the simplified model (13) with the numerical K and the full model (3)-(5) run to steady "
        "state. Reports delta at steady state from both and the steady-state error between them.")
    table1.add_argument("--cases", default="a,b,c,d", help="which cases (default a,b,c,d)")
    table1.add_argument("--nodes", type=int, default=101, help="radial nodes of the full model (default 101)")
    table1.add_argument("--steps-per-period", type=int, default=256,
                        help="time steps per period of the full model (default 256)")
    add_output_options(table1)
    table1.set_defaults(handler=validate_table1)


def calibrate_numerical(args: argparse.Namespace) -> int:
    shape = parse_shape(args.shape)
    sigma = np.sort(args.sigma)
    if args.method == "perturbation":
        K = perturbation_K(shape, sigma, DEFAULT_NODES if args.nodes is None else args.nodes)
    else:
        with progress_bar(sigma.size, "time-marching K(sigma)") as bar:
            K = time_marching_K(shape, sigma, delta=args.delta, nodes=101 if args.nodes is None else args.nodes,
                                steps_per_period=args.steps_per_period, progress=lambda done, total: bar.update(1))
    if args.out:
        TabulatedK(sigma, K, name=f"{args.method}, {shape.name}").save(args.out)
    if args.plot:
        # matplotlib only when plotting
        from nfal.apps.figures.physics import plot_calibration

        plot_calibration(args.plot, sigma, K, label=f"{args.method}, {Path(shape.name).name}",  # a scan: its file name
                         reference=paper_calibration())
    if args.json:
        print_json({"shape": shape.name, "method": args.method, "sigma": sigma, "K": K})
    else:
        print(f"K(sigma), {args.method}, shape {shape.name}")
        print(f"{'sigma':>10} {'K':>12}")
        for s, k in zip(sigma, K):
            print(f"{s:10.4g} {k:12.6g}")
    return 0


def calibrate_experimental(args: argparse.Namespace) -> int:
    rig = rig_from_args(args)
    voltage_map = None
    if args.metres_per_volt is not None:
        voltage_map = VoltageAmplitudeMap.linear(args.metres_per_volt)
    elif args.voltage_map:
        voltage_map = VoltageAmplitudeMap.from_csv(args.voltage_map)
    result = fit_calibration(rig, EquilibriumData.from_csv(args.data, voltage_map), args.degree)
    if args.out:
        result.fit.save(args.out)
    if args.plot:
        # matplotlib only when plotting
        from nfal.apps.figures.physics import plot_experimental_fit

        plot_experimental_fit(args.plot, result, reference=paper_calibration())
    report = result.report()
    if args.json:
        print_json(report)
    else:
        print(f"K(sigma) fitted to {len(report['sigma'])} equilibria, degree {args.degree}, "
              f"sigma {report['sigma_range'][0]:.4g}-{report['sigma_range'][1]:.4g}")
        print("coefficients (ascending powers of sigma, as eq. 17):")
        for power, c in enumerate(report["coefficients"]):
            print(f"  sigma^{power}: {c: .6e}")
        print(f"residuals: rms {report['residual_rms']:.3g}, max {report['residual_max']:.3g}")
    return 0


def validate_table1(args: argparse.Namespace) -> int:
    wanted = [name.strip() for name in args.cases.split(",") if name.strip()]
    known = {case.name: case for case in TABLE1}
    unknown = [name for name in wanted if name not in known]
    if unknown or not wanted:
        raise InvalidParameterError("--cases", args.cases, f"a comma list of {', '.join(known)}")
    shape = paper_shape()
    calibration = perturbation_calibration(shape)
    results = []
    for name in wanted:
        with progress_bar(100, f"Table 1 case {name}") as bar:
            def advance(done: int, total: int, bar=bar) -> None:
                bar.total = total
                bar.n = done
                bar.refresh()

            results.append(run_case(known[name], shape, calibration, nodes=args.nodes,
                                    steps_per_period=args.steps_per_period, progress=advance))
    if args.plot:
        # matplotlib only when plotting
        from nfal.apps.figures.physics import plot_table1

        plot_table1(args.plot, results)
    rows = [result.summary() for result in results]
    if args.json:
        print_json(rows)
    else:
        print("Table 1: delta at steady state, simplified (13) vs full (3)-(5) model; the paper's values in the last "
              "two columns")
        print(f"{'case':>4} {'delta simplified':>17} {'delta full':>11} {'error %':>9} {'paper delta':>12} "
              f"{'paper error %':>14}")
        for row in rows:
            print(f"{row['case']:>4} {row['delta_simplified']:17.4f} {row['delta_full']:11.4f} "
                  f"{row['error_percent']:9.4f} {row['paper_delta']:12.4f} {row['paper_error_percent']:14.4f}")
    return 0
