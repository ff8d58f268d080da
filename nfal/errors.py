"""Every error nfal raises on purpose, in one module importable by every layer (docs/architecture.md).

Each names the bad value and what is allowed (or the element, connector or variable at fault). Bad input
is a :class:`ValueError` subclass; a run, a rig or a host that stops is a :class:`RuntimeError` subclass.
Problems with a structure (what is wired to what, units, types, algebraic loops) are raised before any
FMU runs; problems while a run goes (an FMU answering fmi2Error/fmi2Fatal) while it goes.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence


class NfalError(Exception):
    """Base of every error nfal raises on purpose."""


#: A sequence longer than this is shown as its ends and its length.
SHOWN_ITEMS = 6
#: A value's text longer than this is cut (a message stays one readable line).
SHOWN_CHARACTERS = 200


def shown(value: object) -> str:
    """``value`` as a message shows it: Python's repr, but numpy scalars and arrays as plain numbers and lists (never
    ``np.float64(150.0)`` or a multi-line ``array(...)``), a sequence longer than :data:`SHOWN_ITEMS` as its ends and
    length (``[5e-05, 5.5e-05, ..., 0.0002] (31 values)``), and at most :data:`SHOWN_CHARACTERS` characters."""
    if type(value).__module__ == "numpy" and hasattr(value, "tolist"):
        value = value.tolist()
    if isinstance(value, (list, tuple)) and len(value) > SHOWN_ITEMS:
        text = f"[{shown(value[0])}, {shown(value[1])}, ..., {shown(value[-1])}] ({len(value)} values)"
    elif isinstance(value, list):
        text = "[" + ", ".join(shown(v) for v in value) + "]"
    elif isinstance(value, tuple):
        text = "(" + ", ".join(shown(v) for v in value) + ("," if len(value) == 1 else "") + ")"
    else:
        text = repr(value)
    return text if len(text) <= SHOWN_CHARACTERS else text[:SHOWN_CHARACTERS - 3] + "..."


def span_um(low_m: float, high_m: float) -> str:
    """A range of clearances [m] as messages give it: ``50.0–200.0 µm`` (``120.0 µm`` if both ends are one)."""
    return f"{low_m * 1e6:.1f} µm" if low_m == high_m else f"{low_m * 1e6:.1f}–{high_m * 1e6:.1f} µm"


class InvalidParameterError(NfalError, ValueError):
    """A parameter or input is out of its allowed range (the message names both).

    ``as_shown`` replaces the value's text (default :func:`shown`), e.g. a range of heights as ``50.0–200.0 µm``.
    """

    def __init__(self, name: str, value: object, allowed: str, *, as_shown: str | None = None) -> None:
        self.name, self.value, self.allowed, self.as_shown = name, value, allowed, as_shown
        super().__init__(f"{name} = {shown(value) if as_shown is None else as_shown} is invalid: must be {allowed}")

    def within(self, parent: str) -> "InvalidParameterError":
        """The same error for the field ``parent.name`` (a field of a file's ``parent`` entry)."""
        return InvalidParameterError(f"{parent}.{self.name}", self.value, self.allowed, as_shown=self.as_shown)


class DataFormatError(NfalError, ValueError):
    """A data file (shape scan, equilibrium measurements, calibration) cannot be read as such."""


class ExperimentError(NfalError, RuntimeError):
    """An experiment on the rig stopped: a fault (link lost, touchdown, no settling, drive limit), named."""


class ConvergenceError(NfalError, RuntimeError):
    """An iterative solver did not reach its tolerance."""

# --- numerics -------------------------------------------------------------------------------------

class GapClosedError(ConvergenceError):
    """The film gap closed (H <= 0 at some radius): the surface hit the object; the full model has no contact."""


# --- FMUs and their hosts -------------------------------------------------------------------------

class FmuStateError(NfalError, ValueError):
    """An FMU state that cannot be restored (not from this FMU, or damaged bytes)."""


class SlaveCallError(NfalError, RuntimeError):
    """An FMI call that failed inside our FMU, as the host's logger shows it, the reason first:
    ``"<instance>: <reason> (in <call>)"``."""

    def __init__(self, instance: str, call: str, reason: str) -> None:
        super().__init__(f"{instance}: {reason} (in {call})")


class RuntimeBuildError(NfalError, RuntimeError):
    """The patched FMU runtime cannot be built here (no CMake, no C++ compiler, no Python headers)."""


class HostUnavailableError(NfalError, RuntimeError):
    """A host cannot run here (no C compiler, ecospy or libtbb12 missing)."""


class FirmwareBuildError(NfalError, RuntimeError):
    """The reference firmware (firmware/) cannot be built or started here (no make, C compiler, arm-none-eabi-gcc
    with newlib, or qemu-system-arm: the message names the Debian package)."""


# --- the rig link ---------------------------------------------------------------------------------

class LinkError(NfalError, RuntimeError):
    """The rig cannot be reached, or it does not speak this protocol."""


class RealtimePriorityError(NfalError, PermissionError):
    """The operating system refused a real-time scheduling priority (the message says how to get one)."""


# --- sweeps ---------------------------------------------------------------------------------------

class SweepError(NfalError, RuntimeError):
    """A sweep cannot go on (an unreadable or foreign results table, a missing archive, no cluster)."""


class SweepSpecError(NfalError, ValueError):
    """A sweep spec cannot be read or names a bad key or value (the message says which)."""


# --- plans ----------------------------------------------------------------------------------------

class PlanError(NfalError, ValueError):
    """A command's plan refused before anything starts: longer than its stated bound (and not accepted), beyond what
    can be held, or an option that has no effect in the mode chosen (the message says which, and what to do)."""


# --- orchestration (the master, SSP) -------------------------------------------------------------

class OrchestrationError(NfalError):
    """Base of the errors the orchestrator raises on purpose."""


class StructureError(OrchestrationError, ValueError):
    """An SSP/SSD cannot be read, or what it describes cannot be run (the message says where)."""


class ResultsExistError(OrchestrationError, FileExistsError):
    """A result folder holds a previous run's files, and replacing them was not asked for."""


class UnknownElementError(StructureError):
    """A connection or parameter names an element the system does not have."""


class MissingFmuError(StructureError):
    """A component's ``source`` points at no file (the message gives the resolved path)."""


class UnknownConnectorError(StructureError):
    """A connector, connection end or parameter names a variable the FMU does not declare."""


class CausalityError(StructureError):
    """A connection or connector does not agree with the causality of the variables it joins."""


class UnitMismatchError(StructureError):
    """Two ends of a connection, or a connector and its FMU variable, declare different units."""


class TypeMismatchError(StructureError):
    """Two ends of a connection, or a value and its variable, have different types (Real, Integer...)."""


class UnsupportedFeatureError(StructureError):
    """A valid SSP 1.0 feature this orchestrator does not implement (the message names it)."""


class AlgebraicLoopError(StructureError):
    """The feedthrough graph has a cycle: no order of setting inputs and reading outputs is causal.

    Attributes
    ----------
    variables : tuple of str
        The cycle, as ``Element.variable`` names in the order the values flow.
    """

    def __init__(self, variables: Sequence[str]) -> None:
        self.variables = tuple(variables)
        chain = " -> ".join((*self.variables, self.variables[0])) if self.variables else "?"
        super().__init__(
            f"algebraic loop: {chain}. Every output in the loop is declared to depend directly on the input "
            "before it, so no causal order exists; break the loop (an FMU without direct feedthrough), or run "
            "with algorithm='jacobi' (nfal run --algorithm jacobi), which delays every exchange by one step")


class SignalError(OrchestrationError, ValueError):
    """A reference signal (a CSV of time and value, a step specification) is malformed."""


class SimulationError(OrchestrationError, RuntimeError):
    """A run stopped early. ``result`` (set by :func:`run_structure`) is what was written up to then."""

    result = None


class RunCheckError(SimulationError):
    """A run completed, but a check of its results failed (e.g. the object never lifted off). ``result`` holds
    every row and a summary with status "failed" and the reason."""


class LibcosimUnavailableError(OrchestrationError, RuntimeError):
    """OSP libcosim's Python bindings (``libcosimpy``) are not installed or cannot load."""


class ResultsWriteError(OrchestrationError, OSError):
    """The results cannot be written (a full disk, a file-size limit): the message names the file and the rows kept."""


class FmuLoadError(OrchestrationError, RuntimeError):
    """An FMU cannot be extracted or its shared library loaded here (e.g. no binary for this platform)."""


class FmuCallError(SimulationError):
    """An FMU answered a call with fmi2Error or fmi2Fatal (or worse).

    The message leads with the FMU's own reason (its logged messages, the instance name they start with said once),
    the FMI call after it: ``"Controller: mass = -1.0 is invalid: must be a finite number > 0 (in the set-up from
    the parameters; fmi2GetReal for saturated_time at t = 0 s)"``.

    Attributes
    ----------
    element, function : str
        The element (instance name) and the FMI function, e.g. ``fmi2DoStep``.
    status : int
        The FMI status (3 error, 4 fatal).
    time : float
        The communication point [s] at which the call was made.
    messages : tuple of str
        The FMU's last logged messages (its reason, usually).
    context : str
        What the call was doing, e.g. ``"for saturated_time"`` (may be empty).
    """

    STATUS_NAMES = {0: "ok", 1: "warning", 2: "discard", 3: "error", 4: "fatal", 5: "pending"}

    def __init__(self, element: str, function: str, status: int, time: float, messages: Sequence[str] = (),
                 context: str = "") -> None:
        self.element, self.function, self.status, self.time = element, function, status, time
        self.messages, self.context = tuple(messages), context
        label = self.STATUS_NAMES.get(status, f"illegal status {status}")
        reason = "; ".join(m.removeprefix(f"{element}: ") for m in self.messages) or "the FMU logged no reason"
        call = " ".join(filter(None, (function, context))) + (f" at t = {time:.9g} s" if math.isfinite(time) else "")
        call += "" if status == 3 else f", which returned {label}"
        own = _OWN_CALL.fullmatch(reason)  # our FMUs end their reason with "(in <call>)": one parenthesis for both
        text = f"{own[1]} (in {own[2]}; {call})" if own else f"{reason} (in {call})"
        super().__init__(f"{element}: {text}")


#: A reason that ends with the call it failed in, as our FMUs log it (:class:`SlaveCallError`).
_OWN_CALL = re.compile(r"(.*) \(in ([^()]*)\)", re.DOTALL)


# --- checks --------------------------------------------------------------------------------------

def require_positive(name: str, value: float) -> float:
    """Return ``value`` as float if it is finite and > 0, else raise :class:`InvalidParameterError`."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InvalidParameterError(name, value, "a finite number > 0") from None
    if not (number > 0.0 and number < float("inf")):
        raise InvalidParameterError(name, value, "a finite number > 0")
    return number


def optional_positive(name: str, value: float | None) -> float | None:
    """A setting that 0 (or None) turns off: None then, else ``value`` as float if it is finite and > 0; anything
    else raises :class:`InvalidParameterError`."""
    if value is None:
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InvalidParameterError(name, value, "a finite number >= 0 (0: off)") from None
    if not (0.0 <= number < float("inf")):
        raise InvalidParameterError(name, value, "a finite number >= 0 (0: off)")
    return number or None


def require_finite(name: str, value: float, allowed: str = "a finite number") -> float:
    """Return ``value`` as float if it is finite, else raise :class:`InvalidParameterError` saying ``allowed``."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InvalidParameterError(name, value, allowed) from None
    if not math.isfinite(number):
        raise InvalidParameterError(name, value, allowed)
    return number


def require_non_negative(name: str, value: float, allowed: str = "a finite number >= 0") -> float:
    """Return ``value`` as float if it is finite and >= 0, else raise :class:`InvalidParameterError` saying ``allowed``
    (e.g. "a finite amplitude >= 0 m")."""
    number = require_finite(name, value, allowed)
    if not number >= 0.0:
        raise InvalidParameterError(name, value, allowed)
    return number


#: What an excitation amplitude may be, as every message says it.
AMPLITUDE = "a finite amplitude >= 0 m"


def require_amplitude(name: str, value: float, *, or_function: bool = False) -> float:
    """An amplitude [m]: ``value`` as float if it is finite and >= 0 (:data:`AMPLITUDE`); ``or_function``: the message
    says that a function of time was allowed too."""
    return require_non_negative(name, value, AMPLITUDE + (", or a function of time" if or_function else ""))


def require_duration(name: str, value: float, longest_s: float) -> float:
    """A timeout or wait [s]: ``value`` as float if it is > 0 and at most ``longest_s`` (a wait of a day is a typo, and
    a process that waits for it looks hung), else raise :class:`InvalidParameterError`."""
    allowed = f"a time > 0 s and at most {longest_s:g} s"
    number = require_finite(name, value, allowed)
    if not 0.0 < number <= longest_s:
        raise InvalidParameterError(name, value, allowed)
    return number
