"""Checking a read system structure against its FMUs and flattening it into what a master runs.

:func:`resolve` opens every FMU's modelDescription.xml (fmpy), checks the SSD against it and turns
the hierarchy of systems into a flat :class:`ResolvedSystem`:

* elements with hierarchical names (``Sub.Plant``), each with the start values to set before
  initialisation (from parameter bindings, SSP precedence, then the caller's overrides) and its
  declared direct feedthrough (output -> the inputs it depends on, from ModelStructure);
* links from an element output to an element input, through any chain of system connectors;
* the top-level system's input connectors (``SystemInput``), which a caller drives.

Every inconsistency raises a :class:`~nfal.errors.StructureError` subclass that names
the element and connector: a connector the FMU does not declare, a kind that contradicts the
variable's causality, two ends of a link with different types or units, a connector whose unit is
not the FMU's, a parameter value of the wrong type or unit.

Types: both ends of a link have the same transport type, except that an Integer output may feed a
Real input (converted at the connection, exactly). Nothing else is converted: Real -> Integer would
round, and a Boolean has no agreed number.

Units compare by name first; different names are compatible when both have definitions (SSD
``ssd:Units``, ``ssv:Units`` or the FMU's ``UnitDefinitions``) with the same base-unit exponents,
factor and offset. A side that declares no unit is compatible with any unit. No unit conversion is
ever made; a link with an ``ssc:LinearTransformation`` is the user's own conversion, so its units are
not compared (its ends must be Real, or Integer -> Real). Transformations along a chain of system
connectors compose.

Outputs without a ``dependencies`` attribute: FMI 2.0 reads that as "depends on every input";
docs/cosimulation.md (and pythonfmu, which writes none) as "depends on no input". The default,
``undeclared_dependencies="none"``, follows docs/cosimulation.md; ``"all"`` follows FMI 2.0.
"""

from __future__ import annotations

import dataclasses
import difflib
import logging
import math
from collections.abc import Mapping
from pathlib import Path

from fmpy import read_model_description
from fmpy.model_description import ModelDescription, ModelVariable, ValidationError

from nfal.errors import (CausalityError, InvalidParameterError, StructureError, TypeMismatchError, UnitMismatchError,
                         UnknownConnectorError, UnknownElementError, UnsupportedFeatureError)

from .ssp import (BASE_UNITS, Component, Connector, LinearTransformation, ParameterBinding, ParameterValue, System,
                  SystemStructure, Unit, parse_boolean)

logger = logging.getLogger(__name__)

UNDECLARED_DEPENDENCIES = ("none", "all")
#: FMU variable types the master moves and records, with the transport type of each.
TRANSPORT = {"Real": "Real", "Integer": "Integer", "Enumeration": "Integer", "Boolean": "Boolean", "String": "String"}
#: FMI 3.0 variable types -> the FMI 2.0 type they stand for here (their values cross links as that type).
FMI3_KINDS = {"Float64": "Real", "Float32": "Real", **{f"{sign}Int{bits}": "Integer" for sign in ("", "U")
                                                          for bits in (8, 16, 32, 64)}}
TRANSPORT.update(FMI3_KINDS)


def variable_kind(variable: ModelVariable) -> str:
    """The variable's type as FMI 2.0 names it (Real, Integer, Enumeration, Boolean, String, ...): an FMI 3.0
    Float64 is a Real, an Int32 an Integer."""
    return FMI3_KINDS.get(variable.type, variable.type)


@dataclasses.dataclass(frozen=True)
class Port:
    """A variable of an element, or (``element == ""``) a connector of the top-level system."""

    element: str
    name: str
    type: str | None = None
    unit: str | None = None

    @property
    def path(self) -> str:
        """``Element.variable``, or the connector name for the top-level system."""
        return f"{self.element}.{self.name}" if self.element else self.name


@dataclasses.dataclass(frozen=True)
class Element:
    """An FMU instance of the flattened system.

    Attributes
    ----------
    name : str
        Hierarchical instance name.
    source : Path
        The .fmu file (or extracted folder).
    model_description : fmpy.model_description.ModelDescription
    variables : dict of str to fmpy ModelVariable
    start_values : dict of str to value
        Values to set before initialisation (typed: float, int, bool or str), with ``origins``
        saying where each came from.
    feedthrough : dict of str to tuple of str
        Every output -> the inputs it depends on directly.
    undeclared : tuple of str
        Outputs without a ``dependencies`` declaration (see the module's note).
    """

    name: str
    source: Path
    model_description: ModelDescription = dataclasses.field(repr=False)
    variables: Mapping[str, ModelVariable] = dataclasses.field(repr=False)
    start_values: Mapping[str, object] = dataclasses.field(default_factory=dict)
    origins: Mapping[str, str] = dataclasses.field(default_factory=dict, repr=False)
    feedthrough: Mapping[str, tuple[str, ...]] = dataclasses.field(default_factory=dict)
    undeclared: tuple[str, ...] = ()

    def port(self, name: str) -> Port:
        variable = self.variables[name]
        return Port(self.name, name, variable.type, variable_unit(variable))

    @property
    def outputs(self) -> tuple[str, ...]:
        """Output variable names, in modelDescription order."""
        return tuple(v.name for v in self.model_description.modelVariables if v.causality == "output")


@dataclasses.dataclass(frozen=True)
class Link:
    """Data flow from an element output to an element input; ``via`` lists the system connectors passed.

    ``transformation``: the target receives ``factor * source + offset`` (None: the source's value).
    """

    source: Port
    target: Port
    via: tuple[str, ...] = ()
    transformation: LinearTransformation | None = None


@dataclasses.dataclass(frozen=True)
class SystemInput:
    """An input connector of the top-level system: the element inputs it drives, and its bound value."""

    name: str
    type: str | None
    unit: str | None
    targets: tuple[Port, ...]
    value: object | None = None


@dataclasses.dataclass(frozen=True)
class ResolvedSystem:
    """A system structure checked against its FMUs and flattened (see the module docstring)."""

    name: str
    structure: SystemStructure = dataclasses.field(repr=False)
    elements: tuple[Element, ...]
    links: tuple[Link, ...]
    system_inputs: Mapping[str, SystemInput]
    system_outputs: Mapping[str, Port]
    unmatched_parameters: tuple[str, ...] = ()

    def element(self, name: str) -> Element:
        for element in self.elements:
            if element.name == name:
                return element
        raise UnknownElementError(f"no element named {name!r} (elements: {', '.join(e.name for e in self.elements)})")


def variable_unit(variable: ModelVariable) -> str | None:
    """A variable's unit, from its own attribute or its declared type."""
    if variable.unit:
        return variable.unit
    declared = variable.declaredType
    return declared.unit if declared is not None and declared.unit else None


def fmu_units(model_description: ModelDescription) -> dict[str, Unit]:
    """The FMU's ``UnitDefinitions`` that have a ``BaseUnit``, as :class:`~nfal.orchestration.ssp.Unit`."""
    units = {}
    for unit in model_description.unitDefinitions:
        base = unit.baseUnit
        if base is not None:  # a unit without one says nothing about its dimensions
            units[unit.name] = Unit(unit.name, tuple(int(getattr(base, b)) for b in BASE_UNITS),
                                    float(base.factor), float(base.offset))
    return units


def units_compatible(a: str | None, a_units: Mapping[str, Unit], b: str | None, b_units: Mapping[str, Unit]) -> bool:
    """True when a value in unit ``a`` means the same in unit ``b`` (see the module docstring)."""
    if a is None or b is None or a == b:
        return True
    unit_a, unit_b = a_units.get(a), b_units.get(b)
    return unit_a is not None and unit_b is not None and unit_a.same_as(unit_b)


def load_model_description(name: str, source: Path) -> ModelDescription:
    """Read an FMU's modelDescription.xml; schema problems are logged, not fatal (it may still run)."""
    try:
        try:
            md = read_model_description(str(source), validate=True)
        except ValidationError as exc:
            logger.warning("%s: %s does not validate (running it anyway): %s", name, source.name,
                           "; ".join(map(str, exc.problems)))
            md = read_model_description(str(source), validate=False)
    except Exception as exc:  # fmpy raises bare Exceptions for unreadable FMUs
        raise StructureError(f"element {name!r}: cannot read the modelDescription.xml of {source}: {exc}") from None
    if not str(md.fmiVersion).startswith(("2.", "3.")):
        raise UnsupportedFeatureError(f"element {name!r}: {source.name} is an FMI {md.fmiVersion} FMU; only FMI 2.0 "
                                      "and FMI 3.0 co-simulation FMUs are supported")
    if md.coSimulation is None:
        raise UnsupportedFeatureError(f"element {name!r}: {source.name} has no co-simulation interface "
                                      "(model exchange only)")
    return md


#: Similarity (difflib ratio) above which a parameter name that matches no variable is taken for a typo of one.
MISSPELLING_CUTOFF = 0.85

#: The range of fmi2Integer (a C int): a larger value would reach the FMU cut to 32 bits.
INT32_RANGE = (-2**31, 2**31 - 1)


def _int32(value: int, variable: ModelVariable, where: str) -> int:
    low, high = INT32_RANGE
    if not low <= value <= high:
        raise InvalidParameterError(f"{where}: {variable.name}", value, f"a whole number in [{low}, {high}] "
                                    "(an FMI Integer is 32 bits)")
    return value


def coerce_value(variable: ModelVariable, value: object, where: str, *, strict_type: str | None = None) -> object:
    """``value`` as the Python type that the FMU's ``variable`` takes (float, int, bool or str).

    Strings are parsed by the variable's type ("1e-6", "true", an enumeration item name). With
    ``strict_type`` (the type an .ssv declares), only Integer -> Real widening is allowed.
    """
    kind = variable_kind(variable)
    if strict_type is not None and TRANSPORT.get(strict_type, strict_type) != TRANSPORT.get(kind, kind) \
            and not (strict_type == "Integer" and kind == "Real") \
            and not (strict_type == "Enumeration" and kind in ("Enumeration", "Integer")):
        raise TypeMismatchError(f"{where}: a {strict_type} value for {kind} variable {variable.name!r}")
    bad = TypeMismatchError(f"{where}: {value!r} is not a valid {kind} value for {variable.name!r}")
    if kind == "Real":
        if isinstance(value, bool):
            raise bad
        try:
            return float(value)
        except (TypeError, ValueError):
            raise bad from None
    if kind in ("Integer", "Enumeration"):
        if isinstance(value, bool):
            raise bad
        if isinstance(value, str):
            items = variable.declaredType.items if variable.declaredType is not None else []
            match = next((item for item in items if item.name == value.strip()), None)
            if match is not None:
                return int(match.value)
            try:
                value = float(value)
            except ValueError:
                raise bad from None
        if isinstance(value, float):
            if not (math.isfinite(value) and value == int(value)):
                raise bad
            value = int(value)
        if isinstance(value, int):
            return _int32(value, variable, where)
        raise bad
    if kind == "Boolean":
        if isinstance(value, bool):
            return value
        if isinstance(value, (int, float)) and value in (0, 1):
            return bool(value)
        if isinstance(value, str) and parse_boolean(value) is not None:
            return parse_boolean(value)
        raise bad
    if kind == "String":
        if isinstance(value, str):
            return value
        raise bad
    raise UnsupportedFeatureError(f"{where}: variables of type {kind} are not supported")


def settable_before_initialization(variable: ModelVariable) -> bool:
    """FMI 2.0: variability != constant and (input, parameter, or initial exact/approx)."""
    if variable.variability == "constant":
        return False
    if variable.causality in ("input", "parameter"):
        return True
    return variable.initial in ("exact", "approx")


def resolve(structure: SystemStructure, parameters: Mapping[str, object] | None = None, *,
            undeclared_dependencies: str = "none") -> ResolvedSystem:
    """Check ``structure`` against its FMUs and flatten it.

    Parameters
    ----------
    structure : SystemStructure
        From :func:`~nfal.orchestration.ssp.read_ssp`.
    parameters : mapping, optional
        Overrides applied after the SSD's bindings: ``"Element.variable"`` (hierarchical) or a
        top-level system connector name -> value (typed, or a string parsed by the variable's type).
    undeclared_dependencies : {"none", "all"}
        How to read outputs that declare no ``dependencies`` (see the module docstring).
    """
    if undeclared_dependencies not in UNDECLARED_DEPENDENCIES:
        raise InvalidParameterError("undeclared_dependencies", undeclared_dependencies,
                                    f"one of {UNDECLARED_DEPENDENCIES}")
    return _Resolver(structure, undeclared_dependencies).run(dict(parameters or {}))


@dataclasses.dataclass
class _Node:
    """A connector in the flattened graph: an FMU variable (``component``) or a system connector."""

    owner: str
    name: str
    kind: str
    type: str | None
    unit: str | None
    component: str | None = None  # the element name when this is an FMU variable
    source: "_Node | None" = None
    source_text: str = ""
    transformation: LinearTransformation | None = None  # of the connection from ``source``

    @property
    def path(self) -> str:
        return f"{self.owner}.{self.name}" if self.owner else self.name


class _Resolver:
    def __init__(self, structure: SystemStructure, undeclared: str) -> None:
        self.structure = structure
        self.undeclared = undeclared
        self.components: dict[str, Component] = dict(structure.system.components())
        self.descriptions: dict[str, ModelDescription] = {}
        self.variables: dict[str, dict[str, ModelVariable]] = {}
        self.units: dict[str, dict[str, Unit]] = {}
        self.nodes: dict[tuple[str, str], _Node] = {}
        self.starts: dict[str, dict[str, object]] = {name: {} for name in self.components}
        self.origins: dict[str, dict[str, str]] = {name: {} for name in self.components}
        self.connector_values: dict[tuple[str, str], tuple[object, str]] = {}
        self.unmatched: list[str] = []

    # -- FMUs and their connectors ------------------------------------------------------------------
    def run(self, overrides: dict[str, object]) -> ResolvedSystem:
        for name, component in self.components.items():
            md = load_model_description(name, component.source)
            self.descriptions[name] = md
            self.variables[name] = {v.name: v for v in md.modelVariables}
            self.units[name] = {**self.structure.units, **fmu_units(md)}
            for connector in component.connectors:
                self._check_connector(name, connector)
        self._walk_connections(self.structure.system, "")
        self._walk_bindings()
        for (owner, connector), (value, where) in self.connector_values.items():
            self._propagate(owner, connector, value, where)
        for path, value in overrides.items():  # the command line's after the SSD's: they win
            self._override(path, value)
        links, inputs, outputs = self._flows()
        elements = tuple(self._element(name) for name in self.components)
        if self.unmatched:
            logger.info("parameter values that match no variable (ignored, as SSP 1.0 says): %s",
                        ", ".join(self.unmatched))
        return ResolvedSystem(self.structure.name, self.structure, elements, links, inputs, outputs,
                              tuple(self.unmatched))

    def _check_connector(self, name: str, connector: Connector) -> None:
        variable = self.variables[name].get(connector.name)
        where = f"element {name!r}: connector {connector.name!r}"
        if variable is None:
            raise UnknownConnectorError(f"{where} is not in the FMU's modelDescription "
                                        f"({self.components[name].source.name}"
                                        f"; its inputs: {self._names(name, 'input')}; outputs: "
                                        f"{self._names(name, 'output')})")
        kind = connector.kind
        if kind != variable.causality and not (kind == "parameter" and variable.causality == "input") \
                and not (kind == "input" and variable.causality == "parameter"):
            raise CausalityError(f"{where}: the SSD says kind={kind!r}, "
                                 f"the FMU declares causality={variable.causality!r}")
        if connector.type is not None and TRANSPORT.get(connector.type) != TRANSPORT.get(variable.type):
            raise TypeMismatchError(f"{where}: the SSD says {connector.type}, the FMU declares {variable.type}")
        fmu_unit = variable_unit(variable)
        if not units_compatible(connector.unit, self.structure.units, fmu_unit, self.units[name]):
            raise UnitMismatchError(f"{where}: the SSD says unit {connector.unit!r}, the FMU declares {fmu_unit!r}")

    def _names(self, name: str, causality: str) -> str:
        return ", ".join(v.name for v in self.descriptions[name].modelVariables if v.causality == causality) or "none"

    def _node(self, owner: str, connector: str, element: Component | System | None, system: System,
              where: str) -> _Node:
        key = (owner, connector)
        if key in self.nodes:
            return self.nodes[key]
        if isinstance(element, Component):
            variable = self.variables[owner].get(connector)
            if variable is None:
                raise UnknownConnectorError(f"{where}: element {owner!r} has no variable {connector!r} in its "
                                            f"modelDescription (inputs: {self._names(owner, 'input')}; outputs: "
                                            f"{self._names(owner, 'output')})")
            declared = element.connector(connector)
            unit = declared.unit if declared is not None and declared.unit else variable_unit(variable)
            node = _Node(owner, connector, variable.causality, variable.type, unit, component=owner)
        else:
            target = element if element is not None else system
            declared = target.connector(connector)
            node = _Node(owner, connector, declared.kind, declared.type, declared.unit)
        self.nodes[key] = node
        return node

    def _walk_connections(self, system: System, path: str) -> None:
        for element in system.elements:
            if isinstance(element, System):
                self._walk_connections(element, _join(path, element.name))
        where = f"system {path or system.name!r}"
        for connection in system.connections:
            here = f"{where}: connection {connection.start} -> {connection.end}"
            ends = []
            for element_name, connector in ((connection.start_element, connection.start_connector),
                                            (connection.end_element, connection.end_connector)):
                if element_name is None:
                    ends.append((True, self._node(path, connector, None, system, here)))
                else:
                    owner = _join(path, element_name)
                    ends.append((False, self._node(owner, connector, system.element(element_name), system, here)))
            (a_own, a), (b_own, b) = ends
            source, target = self._direction(a, a_own, b, b_own, here)
            if target.source is not None:
                raise CausalityError(f"{here}: {target.path} already has a source, {target.source.path} "
                                     f"({target.source_text}); an input takes one connection")
            self._check_pair(source, target, here, connection.transformation)
            target.source, target.source_text = source, here
            target.transformation = connection.transformation

    @staticmethod
    def _direction(a: _Node, a_own: bool, b: _Node, b_own: bool, where: str) -> tuple[_Node, _Node]:
        kinds = (a.kind, b.kind)
        if "inout" in kinds:
            raise UnsupportedFeatureError(f"{where}: inout connectors are not supported")
        if a_own == b_own:  # element to element, or the system's own connectors to each other
            if kinds == ("output", "input"):
                return a, b
            if kinds == ("input", "output"):
                return b, a
            if set(kinds) == {"calculatedParameter", "parameter"}:
                raise UnsupportedFeatureError(f"{where}: parameter connections are not supported")
            raise CausalityError(f"{where}: joins {a.path} ({a.kind}) and {b.path} ({b.kind}); one end must be an "
                                 "output and the other an input")
        system_end, element_end = (a, b) if a_own else (b, a)
        if system_end.kind != element_end.kind and not {system_end.kind, element_end.kind} <= {"input", "parameter"}:
            raise CausalityError(f"{where}: system connector {system_end.path} ({system_end.kind}) and "
                                 f"{element_end.path} ({element_end.kind}) must be of the same kind")
        if system_end.kind == "output":
            return element_end, system_end
        if system_end.kind == "calculatedParameter":
            raise UnsupportedFeatureError(f"{where}: parameter connections are not supported")
        return system_end, element_end

    def _unit_table(self, node: _Node) -> Mapping[str, Unit]:
        return self.units[node.component] if node.component else self.structure.units

    def _check_pair(self, source: _Node, target: _Node, where: str,
                    transformation: LinearTransformation | None = None) -> None:
        check_link_types(source.type, target.type, transformation is not None,
                         f"{where}: {source.path} is {source.type}, {target.path} is {target.type}")
        if transformation is not None:
            return
        if not units_compatible(source.unit, self._unit_table(source), target.unit, self._unit_table(target)):
            raise UnitMismatchError(f"{where}: unit mismatch: {source.path} is in {source.unit!r}, "
                                    f"{target.path} in {target.unit!r} (no conversion is made)")

    # -- parameter values ---------------------------------------------------------------------------
    def _walk_bindings(self) -> None:
        entries: list[tuple[int, int, str, str | None, ParameterBinding]] = []

        def walk(system: System, path: str, depth: int) -> None:
            for binding in system.parameter_bindings:
                entries.append((depth, len(entries), path, None, binding))
            for element in system.elements:
                if isinstance(element, System):
                    walk(element, _join(path, element.name), depth + 1)
                else:
                    for binding in element.parameter_bindings:
                        entries.append((depth + 1, len(entries), path, _join(path, element.name), binding))

        walk(self.structure.system, "", 0)
        # SSP 1.0: later bindings at one level win; higher levels win over lower ones.
        for depth, _, path, component, binding in sorted(entries, key=lambda e: (-e[0], e[1])):
            scope = f"element {component!r}" if component else f"system {path or self.structure.system.name!r}"
            origin = f"{binding.origin} bound to {scope}"
            missing = []
            for value in binding.parameter_set.values:
                name = binding.prefix + value.name
                if component is not None:
                    target = (component, name) if name in self.variables[component] else None
                else:
                    target = self._lookup(_join(path, name))
                if target is None:
                    missing.append(name)
                    continue
                self._assign(target, value.value, f"{origin}: {value.name!r}", value, binding)
            for name in missing:
                self._refuse_misspelling(name, component, origin)
            self.unmatched.extend(f"{origin}: {name}" for name in missing)

    def _refuse_misspelling(self, name: str, component: str | None, origin: str) -> None:
        """A parameter name matching no variable is ignored (SSP 1.0: one parameter set may serve several
        components), unless it is a near miss of a variable it can bind: then it is a typo, and an error."""
        if component is not None:
            candidates = list(self.variables[component])
        else:
            candidates = [f"{element}.{variable}" for element, variables in self.variables.items()
                          for variable in variables]
        folded = {candidate.lower(): candidate for candidate in candidates}
        unprefixed = name.rpartition(".")[2]
        if name.lower() in folded:  # names are case-sensitive, and difflib's ratio misses a one-letter case slip
            hint = f"did you mean {folded[name.lower()]!r}?"
        elif component is not None and unprefixed in candidates:
            hint = (f"did you mean {unprefixed!r}? (an element's binding names its variables without the element's "
                    "name: check the binding's prefix)")
        else:
            close = difflib.get_close_matches(name, candidates, n=1, cutoff=MISSPELLING_CUTOFF)
            hint = f"did you mean {close[0]!r}?" if close else None
        if hint:
            raise UnknownConnectorError(f"{origin}: {name!r} matches no variable; {hint}")

    def _lookup(self, full: str) -> tuple[str, str] | None:
        """A hierarchical name -> (element, variable) or (system path, connector) ("" for the top)."""
        best = None
        for name in self.components:
            if full.startswith(name + ".") and full[len(name) + 1:] in self.variables[name]:
                if best is None or len(name) > len(best[0]):
                    best = (name, full[len(name) + 1:])
        if best is not None:
            return best
        owner, _, connector = full.rpartition(".")
        node = self.nodes.get((owner, connector))
        if node is not None and node.component is None:
            return owner, connector
        system = self._system_at(owner)
        if system is not None and system.connector(connector) is not None:
            return owner, connector
        return None

    def _system_at(self, path: str) -> System | None:
        system = self.structure.system
        for part in (path.split(".") if path else []):
            element = system.element(part)
            if not isinstance(element, System):
                return None
            system = element
        return system

    def _assign(self, target: tuple[str, str], value: object, where: str, declared: ParameterValue | None = None,
                binding: ParameterBinding | None = None) -> None:
        owner, name = target
        if owner in self.components and name in self.variables[owner]:
            variable = self.variables[owner][name]
            if not settable_before_initialization(variable):
                raise CausalityError(f"{where}: {owner}.{name} ({variable.causality}, {variable.variability}) "
                                     "cannot be set before initialisation (FMI 2.0: parameters, inputs and variables "
                                     "with initial='exact' or 'approx' can)")
            typed = coerce_value(variable, value, where, strict_type=declared.type if declared else None)
            if declared is not None and declared.unit is not None:
                value_units = {**self.structure.units, **(binding.parameter_set.units if binding else {})}
                unit = variable_unit(variable)
                if not units_compatible(declared.unit, value_units, unit, self.units[owner]):
                    raise UnitMismatchError(f"{where}: value in {declared.unit!r}, {owner}.{name} is in {unit!r}")
            self.starts[owner][name] = typed
            self.origins[owner][name] = where
        else:
            self.connector_values[(owner, name)] = (value, where)

    def _override(self, path: str, value: object) -> None:
        target = self._lookup(path)
        if target is None:
            element, _, variable = path.rpartition(".")
            if element and element not in self.components:
                raise UnknownElementError(f"parameter override {path!r}: no element {element!r} (elements: "
                                          f"{', '.join(self.components)})")
            raise UnknownConnectorError(f"parameter override {path!r}: " + (
                f"{element!r} has no variable {variable!r}" if element else "not a connector of the system; use "
                "Element.variable"))
        self._assign(target, value, f"parameter override {path!r}")
        if target in self.connector_values:  # a system connector's: on to what it feeds, over the SSD's values
            self._propagate(*target, value, f"parameter override {path!r}")

    def _propagate(self, owner: str, connector: str, value: object, where: str) -> None:
        """A value given to a system connector becomes the start value of every FMU variable it feeds."""
        origin = self.nodes.get((owner, connector))
        for node in self.nodes.values():
            if node.component is None:
                continue
            source = node.source
            while source is not None and source is not origin:
                source = source.source
            if source is origin and origin is not None:
                self._assign((node.component, node.name), value, f"{where} (via {origin.path})")

    # -- the flat system ----------------------------------------------------------------------------
    def _flows(self) -> tuple[tuple[Link, ...], dict[str, SystemInput], dict[str, Port]]:
        links, targets = [], {}
        for node in self.nodes.values():
            if node.component is None or node.source is None:
                continue
            via, source, transformation = [], node.source, node.transformation
            while source.component is None and source.source is not None:
                via.append(source.path)
                transformation = _compose(source.transformation, transformation)
                source = source.source
            where = f"{source.path} -> {' -> '.join(via) + ' -> ' if via else ''}{node.path}"
            self._check_pair(source, node, where, transformation)
            if transformation is not None and (node.kind != "input" or source.component is None):
                raise UnsupportedFeatureError(f"{where}: a LinearTransformation is applied on connections from one "
                                              "element's output to another's input only, not from a system input or "
                                              "to a parameter; move it onto such a connection")
            target = Port(node.component, node.name, node.type, node.unit)
            if node.kind != "input":  # a parameter fed by a system connector: its value was set before
                logger.debug("%s: a %s, set from %s before initialisation only", node.path, node.kind, source.path)
            elif source.component is not None:
                links.append(Link(Port(source.component, source.name, source.type, source.unit), target, tuple(via),
                                  transformation))
            elif source.owner == "" and source.kind == "input":
                targets.setdefault(source.name, []).append(target)
            else:
                logger.debug("%s: fed by %s, which nothing drives; keeps its start value", node.path, source.path)
        inputs = {}
        for connector in self.structure.system.connectors:
            if connector.kind != "input":
                continue
            value = self.connector_values.get(("", connector.name), (None, ""))[0]
            inputs[connector.name] = SystemInput(connector.name, connector.type, connector.unit,
                                                 tuple(targets.get(connector.name, ())), value)
        outputs = {}
        for connector in self.structure.system.connectors:
            node = self.nodes.get(("", connector.name))
            if connector.kind == "output" and node is not None and node.source is not None:
                source, transformation = node.source, node.transformation
                while source.component is None and source.source is not None:
                    transformation = _compose(source.transformation, transformation)
                    source = source.source
                if transformation is not None:
                    raise UnsupportedFeatureError(f"system output {connector.name}: a LinearTransformation on its "
                                                  "connection is not applied to system outputs; remove it")
                if source.component is not None:
                    outputs[connector.name] = Port(source.component, source.name, source.type, source.unit)
        return tuple(links), inputs, outputs

    def _element(self, name: str) -> Element:
        md = self.descriptions[name]
        variables = self.variables[name]
        inputs = [v.name for v in md.modelVariables if v.causality == "input"]
        feedthrough, undeclared = {}, []
        declared = {unknown.variable.name: unknown for unknown in md.outputs}
        for variable in md.modelVariables:
            if variable.causality != "output":
                continue
            unknown = declared.get(variable.name)
            if unknown is None or unknown.dependencies is None:
                undeclared.append(variable.name)
                feedthrough[variable.name] = tuple(inputs) if self.undeclared == "all" else ()
            else:
                feedthrough[variable.name] = tuple(d.name for d in unknown.dependencies if d.causality == "input")
        if undeclared:
            logger.info("%s: outputs %s declare no dependencies; read as depending on %s inputs", name,
                        ", ".join(undeclared), "all" if self.undeclared == "all" else "no")
        return Element(name, self.components[name].source, md, variables, dict(self.starts[name]),
                       dict(self.origins[name]), feedthrough, tuple(undeclared))


def check_link_types(source: str | None, target: str | None, transformed: bool, where: str) -> None:
    """Refuse a link between these FMU/connector types (see the module docstring); None: not declared."""
    # by kind, whatever the FMI version names it (an FMI 3.0 Float64 is a Real, an Int32 an Integer)
    source_kind, target_kind = TRANSPORT.get(source, source), TRANSPORT.get(target, target)
    widening = source_kind == "Integer" and source != "Enumeration" and target_kind == "Real"
    if source and target and source_kind != target_kind and not widening:
        raise TypeMismatchError(f"{where}: only Integer -> Real is converted at a connection")
    if transformed and not ({source_kind, target_kind} <= {"Real", None} or widening):
        raise TypeMismatchError(f"{where}: a LinearTransformation needs Real ends (or Integer -> Real)")


def _compose(earlier: LinearTransformation | None, later: LinearTransformation | None) -> LinearTransformation | None:
    if earlier is None or later is None:
        return earlier or later
    return earlier.then(later)


def _join(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name
