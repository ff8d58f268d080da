"""What the command groups share: number-list arguments, JSON output, progress bars."""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np
from tqdm import tqdm


def number_list(text: str) -> np.ndarray:
    """``1,2,5`` (a list) or ``START:STOP:COUNT`` (evenly spaced, both ends included)."""
    try:
        if text.count(":") == 2:
            start, stop, count = text.split(":")
            if int(count) < 1:
                raise ValueError
            return np.linspace(float(start), float(stop), int(count))
        values = np.array([float(item) for item in text.split(",") if item.strip()])
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a list 'A,B,C' nor a range 'START:STOP:COUNT'") from None
    if values.size == 0:
        raise argparse.ArgumentTypeError("an empty list")
    return values


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


def progress_bar(total: int, description: str) -> tqdm:
    """A progress bar on stderr (silent when stderr is not a terminal or under --json pipes)."""
    return tqdm(total=total, desc=description, file=sys.stderr, disable=None, leave=False)


def add_output_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print machine-readable JSON on stdout")
    parser.add_argument("--plot", metavar="FILE", help="write a PNG figure to FILE")
