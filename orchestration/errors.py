"""The orchestrator's error types: every one names the element, connector or variable at fault.

Problems with a structure (what is wired to what, units, types, algebraic loops) are
:class:`ValueError` subclasses and are raised before any FMU runs; problems while a run goes
(an FMU answering fmi2Error/fmi2Fatal) are :class:`RuntimeError` subclasses.
"""

from __future__ import annotations

from collections.abc import Sequence

from nfal.models.errors import NfalError


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
            "with algorithm='jacobi', which delays every exchange by one step")


class SignalError(OrchestrationError, ValueError):
    """A reference signal (a CSV of time and value, a step specification) is malformed."""


class SimulationError(OrchestrationError, RuntimeError):
    """A run stopped early. ``result`` (set by :func:`run_structure`) is what was written up to then."""

    result = None


class FmuLoadError(OrchestrationError, RuntimeError):
    """An FMU cannot be extracted or its shared library loaded here (e.g. no binary for this platform)."""


class FmuCallError(SimulationError):
    """An FMU answered a call with fmi2Error or fmi2Fatal (or worse).

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
    """

    STATUS_NAMES = {0: "ok", 1: "warning", 2: "discard", 3: "error", 4: "fatal", 5: "pending"}

    def __init__(self, element: str, function: str, status: int, time: float, messages: Sequence[str] = ()) -> None:
        self.element, self.function, self.status, self.time = element, function, status, time
        self.messages = tuple(messages)
        label = self.STATUS_NAMES.get(status, f"illegal status {status}")
        reason = "; ".join(self.messages) if self.messages else "the FMU logged no reason"
        super().__init__(f"{element}: {function} returned {label} at t = {time:.9g} s: {reason}")
