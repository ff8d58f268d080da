"""What the command groups share: number-list arguments, JSON output, progress bars."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from nfal.errors import PlanError
from nfal.models.rig import RigParameters
from nfal.models.step_metrics import noise_limits_settling


def finite_float(text: str) -> float:
    """An argparse type: a finite number (``nan``, ``inf`` and words are usage errors, exit code 2)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r}: must be a finite number")
    return value


def positive_float(text: str) -> float:
    """An argparse type: a finite number > 0."""
    value = finite_float(text)
    if value <= 0.0:
        raise argparse.ArgumentTypeError(f"{text!r}: must be a finite number > 0")
    return value


#: Figure formats --plot writes (by the file's extension).
PLOT_FORMATS = (".png", ".pdf", ".svg")


def output_file(*suffixes: str):
    """An argparse type: a file to write, ending in one of ``suffixes``, in a folder that exists and is writable
    (checked before any work is done, so a long computation does not end in a failed write)."""
    def check(text: str) -> str:
        path = Path(text)
        if path.suffix.lower() not in suffixes:
            raise argparse.ArgumentTypeError(f"{text!r}: the file must end in {' or '.join(suffixes)}")
        folder = path.parent if str(path.parent) else Path(".")
        if not folder.is_dir():
            raise argparse.ArgumentTypeError(f"{text!r}: no folder {str(folder)!r} to write it in")
        if not os.access(folder, os.W_OK) or path.is_dir():
            raise argparse.ArgumentTypeError(f"{text!r}: cannot be written "
                                             "(folder not writable, or a folder by that name)")
        return text
    return check


#: Most values a number list may hold (a mistyped COUNT would allocate gigabytes before anything is computed).
MAX_LIST_VALUES = 100_000


def number_list(text: str) -> np.ndarray:
    """``1,2,5`` (a list) or ``START:STOP:COUNT`` (evenly spaced, both ends included; at most
    :data:`MAX_LIST_VALUES`)."""
    try:
        if text.count(":") == 2:
            start, stop, count = text.split(":")
            if int(count) < 1:
                raise ValueError
            if int(count) > MAX_LIST_VALUES:
                raise argparse.ArgumentTypeError(f"{text!r}: {int(count):,} values; at most {MAX_LIST_VALUES:,}")
            values = np.linspace(float(start), float(stop), int(count))
        else:
            values = np.array([float(item) for item in text.split(",") if item.strip()])
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a list 'A,B,C' nor a range 'START:STOP:COUNT'") from None
    if values.size == 0:
        raise argparse.ArgumentTypeError("an empty list")
    if not np.all(np.isfinite(values)):
        raise argparse.ArgumentTypeError(f"{text!r}: every value must be a finite number")
    return values


def add_accept_long_plan(parser: argparse.ArgumentParser, bound: str) -> None:
    """--accept-long-plan: run a plan longer than the command's stated ``bound`` (refused otherwise)."""
    parser.add_argument("--accept-long-plan", action="store_true", help=f"run a plan longer than {bound} (without it, "
                        "such a plan is refused before anything starts, with its length)")


def refuse_given(options: dict[str, object], reason: str) -> None:
    """Refuse the first of ``options`` (flag -> parsed value) that was given: it has no effect ``reason`` (e.g.
    "without --port (...)"). Not given: None, False or an empty list (such options default to those)."""
    for flag, value in options.items():
        if not (value is None or value is False or (isinstance(value, list) and not value)):
            raise PlanError(f"{flag} has no effect {reason}")


def fill_defaults(args: argparse.Namespace, defaults: dict[str, object]) -> None:
    """Set each option of ``defaults`` (dest -> value) left at None: options whose default is None so that
    :func:`refuse_given` can tell them given."""
    for dest, value in defaults.items():
        if getattr(args, dest) is None:
            setattr(args, dest, value)


def duration_text(seconds: float) -> str:
    """``41 s``, ``12.5 min``, ``1 h``, ``4.5 days``: a plan's length for a person."""
    for unit, size in (("days", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if seconds >= size:
            return f"{seconds / size:.1f}".rstrip("0").rstrip(".") + f" {unit}"
    return f"{seconds:.0f} s"


def steal_text(steal: dict | None) -> str | None:
    """A real-time report's ``steal`` (nfal.realtime.StealWatch) as a line, or None if there was none to speak of."""
    if not steal or not steal.get("worst_second_percent"):
        return None
    return (f"the machine's hypervisor took {steal['share_percent']:.2f} % of the vCPUs over the loop (time no "
            f"process here could use), {steal['worst_second_percent']:.1f} % in its worst second (ending "
            f"{steal['worst_second_at_s']:.1f} s in) and {steal['last_second_percent']:.1f} % in its last")


def print_json(data) -> None:
    """Write ``data`` as JSON on stdout (numpy arrays and numbers converted)."""
    json.dump(data, sys.stdout, indent=2, default=_to_builtin)
    sys.stdout.write("\n")


def _to_builtin(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot write {type(value).__name__} as JSON")


def print_step_table(steps: list[dict]) -> None:
    """The per-step metrics (``StepMetrics.to_dict()`` rows) as an indented table in ms, %, nm and um s; a rise or
    settling time the step never reached is shown as "-", one its noise decides is marked "*" (both explained under
    the table)."""
    def show(value, scale, width, mark=""):
        return f"{'-':>{width}}" if value is None else f"{value * scale:{width - len(mark)}.1f}{mark}"
    print(f"  {'step [um]':>13} {'rise [ms]':>9} {'overshoot [%]':>13} {'settle [ms]':>11} {'noise [nm]':>10} "
          f"{'IAE [um s]':>10}")
    for step in steps:
        mark = "*" if noise_limits_settling(step) else ""
        print(f"  {step['from_m'] * 1e6:5.0f} -> {step['to_m'] * 1e6:4.0f} {show(step['rise_time_s'], 1e3, 9)} "
              f"{step['overshoot_percent']:13.1f} {show(step['settling_time_s'], 1e3, 11, mark)} "
              f"{step['noise_rms_m'] * 1e9:10.1f} {step['iae'] * 1e6:10.3f}")
    if any(step["rise_time_s"] is None or step["settling_time_s"] is None for step in steps):
        print("  (-: not reached within the step: no 10-90 % rise, or not settled within 2 % by its end)")
    if any(noise_limits_settling(step) and step["settling_time_s"] is not None for step in steps):
        print("  (*: limited by noise: the 2 % band is narrower than three times the height's noise RMS, so the time "
              "is when the noise last left the band, not when the object settled; rise time and overshoot still hold)")


def progress_bar(total: int, description: str) -> tqdm:
    """A progress bar on stderr (silent when stderr is not a terminal or under --json pipes)."""
    return tqdm(total=total, desc=description, file=sys.stderr, disable=None, leave=False)


def add_output_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print machine-readable JSON on stdout")
    parser.add_argument("--plot", metavar="FILE", type=output_file(*PLOT_FORMATS),
                        help=f"write a figure to FILE ({', '.join(f[1:].upper() for f in PLOT_FORMATS)}, "
                        "by its extension)")


RIG_OPTIONS = (
    ("mass", "kg", "mass of the levitated object"),
    ("radius", "m", "radius r0 of object and driving surface"),
    ("frequency", "Hz", "excitation frequency"),
    ("viscosity", "Pa s", "dynamic viscosity of the gas"),
    ("ambient_pressure", "Pa", "ambient pressure"),
    ("reference_clearance", "m", "reference clearance h0 of eq. (2)"),
)


def add_rig_options(parser: argparse.ArgumentParser) -> None:
    """--mass, --radius, ... overriding the paper's rig (defaults shown by --help)."""

    defaults = RigParameters()
    group = parser.add_argument_group("rig (SI; defaults: the paper's rig)")
    for name, unit, text in RIG_OPTIONS:
        group.add_argument(f"--{name.replace('_', '-')}", dest=f"rig_{name}", type=finite_float, metavar=unit,
                           help=f"{text} [{unit}] (default {getattr(defaults, name):g})")


def rig_from_args(args: argparse.Namespace):
    changes = {name: getattr(args, f"rig_{name}") for name, _, _ in RIG_OPTIONS
               if getattr(args, f"rig_{name}") is not None}
    return RigParameters(**changes)
