"""The project's error types: every bad input raises one of these, naming the value and the range."""

from __future__ import annotations

import math


class NfalError(Exception):
    """Base of every error nfal raises on purpose."""


class InvalidParameterError(NfalError, ValueError):
    """A parameter or input is out of its allowed range (the message names both)."""

    def __init__(self, name: str, value: object, allowed: str) -> None:
        self.name, self.value, self.allowed = name, value, allowed
        super().__init__(f"{name} = {value!r} is invalid: must be {allowed}")


class DataFormatError(NfalError, ValueError):
    """A data file (shape scan, equilibrium measurements, calibration) cannot be read as such."""


class ExperimentError(NfalError, RuntimeError):
    """An experiment on the rig stopped: a fault (link lost, touchdown, no settling, drive limit), named."""


class ConvergenceError(NfalError, RuntimeError):
    """An iterative solver did not reach its tolerance."""


def require_positive(name: str, value: float) -> float:
    """Return ``value`` as float if it is finite and > 0, else raise :class:`InvalidParameterError`."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InvalidParameterError(name, value, "a finite number > 0") from None
    if not (number > 0.0 and number < float("inf")):
        raise InvalidParameterError(name, value, "a finite number > 0")
    return number


def require_finite(name: str, value: float, allowed: str = "a finite number") -> float:
    """Return ``value`` as float if it is finite, else raise :class:`InvalidParameterError` saying ``allowed``."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InvalidParameterError(name, value, allowed) from None
    if not math.isfinite(number):
        raise InvalidParameterError(name, value, allowed)
    return number
