"""The numbers of a JSON data file (a calibration file), read exactly: each error names the field and its value.

JSON ``true`` is a bool and ``"1"`` a string: neither is a number here (numpy would read them as 1.0), nor are
``NaN`` and ``1e999`` (which Python's reader accepts).
"""

from __future__ import annotations

import json
import math

from nfal.errors import SHOWN_CHARACTERS, InvalidParameterError


def as_json(value: object) -> str:
    """``value`` as the file spells it (``true``, ``"1"``), cut to :data:`~nfal.errors.SHOWN_CHARACTERS`."""
    text = json.dumps(value)
    return text if len(text) <= SHOWN_CHARACTERS else text[:SHOWN_CHARACTERS - 3] + "..."


def json_number(field: str, value: object) -> float:
    """``value`` as float if it is a finite JSON number (an int or a float: not a bool, NaN or 1e999), else raise
    :class:`InvalidParameterError` naming ``field``."""
    if type(value) not in (int, float) or not math.isfinite(value):
        raise InvalidParameterError(field, value, "a finite number", as_shown=as_json(value))
    return float(value)


def json_numbers(field: str, value: object) -> list[float]:
    """``value`` as floats if it is a JSON list of numbers (each as :func:`json_number`, named ``field[i]``)."""
    if not isinstance(value, list):
        raise InvalidParameterError(field, value, "a list of numbers", as_shown=as_json(value))
    return [json_number(f"{field}[{i}]", item) for i, item in enumerate(value)]
