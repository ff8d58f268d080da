"""The fixed-step co-simulation master over fmpy: any FMI 2.0 or FMI 3.0 co-simulation FMUs, mixed at will.

Two algorithms (docs/cosimulation.md, "The loop and the step order"), one class each in :mod:`.exchange`:

``causal`` (default)
    At each communication point t_k, set inputs and read outputs in the causal order of the
    feedthrough graph (:func:`~nfal.orchestration.schedule.causal_sweep`: an output is read only
    after every input it depends on is set, an input is set only after its source output is read),
    then ``doStep(t_k, dt)`` every FMU. With no algebraic loop every value exchanged at t_k is the
    value at t_k: zero delay, as in the pure-Python sampled loop. An algebraic loop is an error.

``jacobi``
    OSP libcosim's fixed-step algorithm: set every input from the last exchange, ``doStep`` every
    FMU, then read every output and move it to the inputs it feeds (used at the next step). Every
    FMU with feedthrough adds one step of delay; algebraic loops are broken by that delay.
    Initialisation, as libcosim (``fixed_step_algorithm::initialize``): as many rounds of (set the
    inputs, read all outputs, move them to the inputs) as there are FMUs, in initialisation mode; then
    exit initialisation, read the outputs again and move them once more, so the first step starts
    from the outputs of the running FMUs at t0.

Every run: extract each FMU (once per process and content, :mod:`~nfal.orchestration.fmu_folders`; for each run
if it can be instantiated only once per process),
instantiate it with a logger that keeps its last messages, set the start values (typed), set up the
experiment, enter initialisation, set the external inputs at t0 and propagate (per algorithm), exit
initialisation. The master's ``row`` holds every recorded value at the current communication point:
``[time, external inputs..., every output of every element...]`` (see ``columns``).

An external input given for an input that a connection feeds replaces that connection for the run (logged),
as a host's override does (libcosim's override manipulator): ``nfal run --reference`` drives
``Controller.reference`` in place of the structure's ReferenceGenerator.

FMI 3.0 (fmpy's ``FMU3Slave``): the same steps without ``setupExperiment`` (start and stop go to
``fmi3EnterInitializationMode``); Float64/Float32 variables are Reals, Int8..UInt64 Integers (an
Enumeration travels as Int64); a ``doStep`` that returns ``terminateSimulation`` ends the run at its
``lastSuccessfulTime`` as an FMI 2.0 horizon end does.

Values cross a link as the target's type (Integer -> Real) and through its ``LinearTransformation``,
if any (:mod:`~nfal.orchestration.resolve`). An FMU that ends its own horizon (fmi2Discard from
doStep and fmi2Terminated true) sets :attr:`Master.ended` (a :class:`HorizonEnd`), not an error.
Any other failing call (fmi2Error, fmi2Fatal, fmi2Discard from doStep) raises
:class:`~nfal.errors.FmuCallError`: the element and the FMU's logged reason first (an error-status message
before any earlier warning), then the function, what it was for and the time. :meth:`Master.close` then
frees what can be freed (an instance in error is freed without fmi2Terminate; after fmi2Fatal, FMI allows
no further call to that FMU, so none is made).
"""

from __future__ import annotations

import collections
import ctypes
import dataclasses
import itertools
import logging
import shutil
import time
import weakref
from collections.abc import Callable, Mapping

from fmpy import calloc, extract, free
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (FMU2Slave, fmi2Boolean, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, fmi2Discard, fmi2Integer, fmi2Real, fmi2True,
                       fmi2ValueReference, fmi2Warning)
from fmpy.fmi3 import FMU3Slave, fmi3Boolean, fmi3Float64, fmi3True, fmi3ValueReference
from fmpy.logging import addLoggerProxy

from nfal.errors import (CausalityError, FmuCallError, FmuLoadError, InvalidParameterError,
                         TypeMismatchError, UnknownConnectorError, UnsupportedFeatureError, require_positive, shown)

from . import fmu_folders
from .compiled_exchange import compiled_step
from .resolve import TRANSPORT, Element, ResolvedSystem, variable_unit
from .results import Column
from .exchange import EXCHANGES
from .schedule import Action
from .signals import as_signal
from .ssp import LinearTransformation

logger = logging.getLogger(__name__)

ALGORITHMS = tuple(EXCHANGES)
FMU_LOGGING = ("on", "off")
_STATUS_LEVELS = {0: logging.DEBUG, 1: logging.WARNING, 2: logging.WARNING, 3: logging.ERROR, 4: logging.ERROR}
#: What pythonfmu's C wrapper logs after any Python exception, whatever the FMU logged before it.
_PYTHONFMU_AFTER_REASON = "Fatal py exception encountered"
_CTYPES = {"Real": fmi2Real, "Integer": fmi2Integer, "Boolean": fmi2Boolean}
_CONVERT: dict[str, Callable[[float], object]] = {"Real": float, "Integer": lambda v: int(round(v)),
                                                   "Boolean": lambda v: int(bool(v))}
_ORDER = ("Real", "Integer", "Boolean")
#: FMI 3.0: the function suffix (fmi3Get<X>/fmi3Set<X>, FMU3Slave.set<X>) and C type of each variable type.
_FMI3_CALLS = {"Float64": ("Float64", ctypes.c_double), "Float32": ("Float32", ctypes.c_float),
               "Boolean": ("Boolean", ctypes.c_bool), "Enumeration": ("Int64", ctypes.c_int64),
               **{f"{sign}Int{bits}": (f"{sign}Int{bits}", getattr(ctypes, f"c_{sign.lower()}int{bits}"))
                  for sign in ("", "U") for bits in (8, 16, 32, 64)}}
#: FMI 2.0: the same (the transport type names the functions).
_FMI2_CALLS = {"Real": ("Real", fmi2Real), "Integer": ("Integer", fmi2Integer), "Enumeration": ("Integer", fmi2Integer),
               "Boolean": ("Boolean", fmi2Boolean)}


def _direct(slave: "_Slave", name: str) -> Callable:
    """The FMI function ``name`` of ``slave``'s library as ctypes calls it, typed by fmpy, for the calls of every
    step: fmpy's wrapper around it (call logging, the status check) took 5 % of a fig7 loop. :func:`_checked` checks
    the status as the wrapper does."""
    return getattr(slave.fmu.dll, name)


def _checked(name: str, status: int) -> None:
    """fmpy's check of a call's status: an error (or discard, or fatal) raised as fmpy raises it (fmi3Warning is
    fmi2Warning's 1 too)."""
    if status > fmi2Warning:
        raise FMICallException(function=name, status=status)


def _route_log(environment, instance, status, category, message) -> None:
    """The one logger callback of every instance: fmpy's native proxy (which formats the variadic
    message) keeps a single, process-wide Python logger, so messages are routed here by the
    component environment each instance was given (its instance name as a fallback)."""
    try:
        slave = _SLAVES.get(environment) if environment else None
        if slave is None:
            name = instance.decode("utf-8", "replace") if instance else "?"
            slave = next((s for s in list(_SLAVES.values()) if s.name == name), None)
        text = message.decode("utf-8", "replace") if message else ""
        level = _STATUS_LEVELS.get(status, logging.ERROR)
        if slave is not None:
            name = slave.name
            if status >= 1 and not (text.startswith(_PYTHONFMU_AFTER_REASON) and slave.reasons):
                slave.messages.append(text)
            if status >= 3:  # the failing call's FmuCallError carries the messages: said once, there
                level = logging.DEBUG
                slave.reasons.append(text)
        logger.log(level, "[%s] %s", name, text)
    except Exception:  # pragma: no cover - never let an exception cross the C callback
        pass


_LOGGER = fmi2CallbackLoggerTYPE(_route_log)
_SLAVES: "weakref.WeakValueDictionary[int, _Slave]" = weakref.WeakValueDictionary()
_NEXT_ID = itertools.count(1)


class _Slave:
    """One FMI 2.0 FMU instance: the fmpy object, its callbacks and what became of it."""

    fmi = 2
    CALLS = _FMI2_CALLS  #: variable type -> (suffix of its get/set functions, C value type)

    FMU_CLASS = FMU2Slave  #: fmpy's class of the instance

    def __init__(self, element: Element, unzip_dir: str, fmu_logging: str) -> None:
        self._load(element, unzip_dir, fmu_logging)
        self.id = next(_NEXT_ID)
        _SLAVES[self.id] = self
        self.callbacks = fmi2CallbackFunctions()
        self.callbacks.logger = _LOGGER
        self.callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        self.callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self.callbacks.componentEnvironment = self.id
        try:
            addLoggerProxy(ctypes.byref(self.callbacks))
        except Exception as exc:  # pragma: no cover - fmpy ships the proxy for every platform it supports
            logger.warning("no fmpy logger proxy (%s): FMU messages arrive unformatted", exc)

    def _load(self, element: Element, unzip_dir: str, fmu_logging: str) -> None:
        """What every instance holds, and its FMU loaded from ``unzip_dir`` (its library, not yet instantiated)."""
        self.element, self.name, self.folder = element, element.name, unzip_dir
        self.messages: collections.deque[str] = collections.deque(maxlen=20)
        #: The error-status messages: an error's cause, said first (pythonfmu's generic follow-up to one adds nothing)
        self.reasons: collections.deque[str] = collections.deque(maxlen=5)
        self.state = "loaded"  # -> instantiated -> initialization -> running -> freed; error; fatal
        self.step_time = 0.0
        self.fmu_logging = fmu_logging
        md = element.model_description
        try:
            self.fmu = self.FMU_CLASS(guid=md.guid, unzipDirectory=unzip_dir,
                                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName=element.name)
        except Exception as exc:  # fmpy raises bare Exceptions for missing or unloadable binaries
            raise FmuLoadError(f"element {self.name!r}: cannot load {element.source.name}: {exc}") from None

    def instantiate(self) -> None:
        try:
            self.fmu.instantiate(callbacks=self.callbacks, loggingOn=self.fmu_logging != "off")
        except Exception as exc:
            raise FmuCallError(self.name, "fmi2Instantiate", 3, float("nan"), [*self.messages, str(exc)]) from None
        self._instantiated()

    def _instantiated(self) -> None:
        self.component = self.fmu.component
        self._do_step = _direct(self, f"fmi{self.fmi}DoStep")  # called every step: straight to the library
        self.state = "instantiated"

    def calls(self, type_: str) -> tuple[str, type]:
        """The suffix of the get/set functions of variables of ``type_`` and their C value type."""
        if type_ not in self.CALLS:
            raise UnsupportedFeatureError(f"element {self.name!r}: {type_} variables cannot be exchanged")
        return self.CALLS[type_]

    def set_start(self, variable, value) -> None:
        suffix = "String" if variable.type == "String" else self.CALLS.get(variable.type, (None,))[0]
        if suffix is None:
            raise UnsupportedFeatureError(f"{self.name}.{variable.name}: cannot set a {variable.type} variable")
        getattr(self.fmu, f"set{suffix}")([variable.valueReference], [value])

    def setup_experiment(self, start_time: float, stop_time: float | None) -> None:
        self.fmu.setupExperiment(startTime=start_time, stopTime=stop_time)

    def enter_initialization_mode(self) -> None:
        self.fmu.enterInitializationMode()

    def do_step(self, t: float, dt: float) -> None:
        _checked("fmi2DoStep", self._do_step(self.component, t, dt, fmi2True))


class _Slave3(_Slave):
    """One FMI 3.0 co-simulation FMU instance (fmpy's FMU3Slave): as :class:`_Slave`, with FMI 3.0's calls."""

    fmi = 3
    CALLS = _FMI3_CALLS

    FMU_CLASS = FMU3Slave

    def __init__(self, element: Element, unzip_dir: str, fmu_logging: str) -> None:
        self._load(element, unzip_dir, fmu_logging)
        # FMI 3.0's logger has no instance name: one callback per instance, which knows its slave
        slave = weakref.ref(self)
        self._log_message = lambda environment, status, category, message: _log3(slave(), status, message)
        self._event, self._terminate, self._early = fmi3Boolean(), fmi3Boolean(), fmi3Boolean()
        self._last = fmi3Float64()
        self._step_flags = (ctypes.byref(self._event), ctypes.byref(self._terminate), ctypes.byref(self._early),
                            ctypes.byref(self._last))

    def instantiate(self) -> None:
        try:
            self.fmu.instantiate(loggingOn=self.fmu_logging != "off", logMessage=self._log_message)
        except Exception as exc:
            raise FmuCallError(self.name, "fmi3InstantiateCoSimulation", 3, float("nan"),
                               [*self.messages, str(exc)]) from None
        self._instantiated()

    def setup_experiment(self, start_time: float, stop_time: float | None) -> None:
        self._experiment = (start_time, stop_time)  # FMI 3.0 has no setupExperiment: they go with the next call

    def enter_initialization_mode(self) -> None:
        start_time, stop_time = self._experiment
        self.fmu.enterInitializationMode(startTime=start_time, stopTime=stop_time)

    def do_step(self, t: float, dt: float) -> float | None:
        """One fmi3DoStep; None, or the last successful time when the FMU asks to terminate the simulation."""
        self._terminate.value = False  # what an FMU that does not write it says (the compiled step's too)
        _checked("fmi3DoStep", self._do_step(self.component, t, dt, fmi3True, *self._step_flags))
        return self._last.value if self._terminate.value else None


def _log3(slave: "_Slave | None", status: int, message: bytes | None) -> None:
    """The FMI 3.0 logger of ``slave`` (one per instance), routed as FMI 2.0 messages are."""
    try:
        text = message.decode("utf-8", "replace") if message else ""
        level = _STATUS_LEVELS.get(status, logging.ERROR)
        name = "?"
        if slave is not None:
            name = slave.name
            if status >= 1:
                slave.messages.append(text)
            if status >= 3:  # the failing call's FmuCallError carries the messages
                level = logging.DEBUG
                slave.reasons.append(text)
        logger.log(level, "[%s] %s", name, text)
    except Exception:  # pragma: no cover - never let an exception cross the C callback
        pass


def _slave(element: Element, unzip_dir: str, fmu_logging: str) -> _Slave:
    """The instance of ``element``'s FMU for its FMI version."""
    major = str(element.model_description.fmiVersion).split(".")[0]
    return (_Slave3 if major == "3" else _Slave)(element, unzip_dir, fmu_logging)


class _Transfer:
    """One fmi2Set<Type> or fmi2Get<Type> call: value references, a value buffer and row columns."""

    __slots__ = ("slave", "kind", "type", "names", "vr", "n", "buffer", "name", "function", "component", "pairs",
                 "scaled", "run", "count", "boolean")

    def __init__(self, slave: _Slave, kind: str, type_: str, names: tuple[str, ...], columns: tuple[int, ...],
                 immediate: bool, transformations: tuple[LinearTransformation | None, ...] = ()) -> None:
        variables = slave.element.variables
        self.slave, self.kind, self.type, self.names = slave, kind, type_, names
        self.n = len(names)
        suffix, value_type = slave.calls(type_)
        reference = fmi3ValueReference if slave.fmi == 3 else fmi2ValueReference
        self.vr = (reference * self.n)(*(variables[n].valueReference for n in names))
        self.buffer = (value_type * self.n)()
        self.name = f"fmi{slave.fmi}{kind.capitalize()}{suffix}"
        self.function = _direct(slave, self.name)
        self.count = (self.n,) if slave.fmi == 3 else ()  # FMI 3.0's nValues
        self.boolean = slave.fmi == 3 and value_type is ctypes.c_bool  # read as 0/1, as FMI 2.0's fmi2Boolean
        transformations = transformations or (None,) * self.n
        # set: most values are copied; a connection's LinearTransformation is applied on the way
        self.pairs = tuple((j, c) for j, (c, f) in enumerate(zip(columns, transformations)) if f is None)
        self.scaled = tuple((j, c, f.factor, f.offset) for j, (c, f) in enumerate(zip(columns, transformations))
                            if f is not None)
        self.component = None
        # get: read into the row; set: (causal) copy from the row and set now, (jacobi) set what was loaded
        self.run = self.get if kind == "get" else (self.load_and_push if immediate else self.push)

    def bind(self) -> None:
        self.component = self.slave.component

    def get(self, row: list) -> None:
        buffer = self.buffer
        _checked(self.name, self.function(self.component, self.vr, self.n, buffer, *self.count))
        if self.boolean:
            for j, column in self.pairs:
                row[column] = int(buffer[j])
            return
        for j, column in self.pairs:
            row[column] = buffer[j]

    def load(self, row: list) -> None:
        buffer = self.buffer
        for j, column in self.pairs:
            buffer[j] = row[column]
        for j, column, factor, offset in self.scaled:
            buffer[j] = factor * row[column] + offset

    def push(self, row: list | None = None) -> None:
        _checked(self.name, self.function(self.component, self.vr, self.n, self.buffer, *self.count))

    def load_and_push(self, row: list) -> None:
        self.load(row)
        self.push()


_FMI2_LAST_SUCCESSFUL_TIME, _FMI2_TERMINATED = 2, 3  # fmi2StatusKind


@dataclasses.dataclass(frozen=True)
class HorizonEnd:
    """An FMU ended its own horizon: fmi2Discard from doStep, then fmi2Terminated true (FMI 2.0).

    ``time_s`` is its last successful time; ``step_completed`` whether that is the end of the step.
    """

    element: str
    time_s: float
    step_completed: bool
    messages: list[str] = dataclasses.field(default_factory=list)
    how: str = "fmi2Discard from fmi2DoStep, fmi2Terminated"

    @property
    def note(self) -> str:
        return (f"{self.element} ended its own horizon at t = {self.time_s:g} s ({self.how}); the run stops there"
                + (f": {self.messages[-1]}" if self.messages else ""))


class Master:
    """Runs a :class:`~nfal.orchestration.resolve.ResolvedSystem` with a fixed communication step.

    Parameters
    ----------
    system : ResolvedSystem
    step_size : float
        Communication step [s].
    algorithm : {"causal", "jacobi"}
        See the module docstring.
    inputs : mapping, optional
        External inputs: ``"Element.variable"`` (an input; if a connection feeds it, this replaces the
        connection) or the name of an input connector of the top-level system -> a function of time [s]
        or a constant (SI). A top-level
        input connector with a bound value and no entry here is held at that value.
    fmu_logging : {"on", "off"}
        Instantiate with logging on (default: every category; messages go to this module's logger,
        OK ones at DEBUG, and the last warnings/errors into :class:`FmuCallError`) or off (some FMUs
        then keep their reasons to themselves).

    Use as a context manager, or call :meth:`close`. Usage: ``instantiate()``, ``initialize(t0)``,
    then ``step()`` repeatedly; ``row`` holds the values at ``time`` after each.
    """

    def __init__(self, system: ResolvedSystem, *, step_size: float, algorithm: str = "causal",
                 inputs: Mapping[str, object] | None = None, fmu_logging: str = "on") -> None:
        if algorithm not in ALGORITHMS:
            raise InvalidParameterError("algorithm", algorithm, f"one of {ALGORITHMS}")
        if fmu_logging not in FMU_LOGGING:
            raise InvalidParameterError("fmu_logging", fmu_logging, f"one of {FMU_LOGGING}")
        self.system, self.algorithm, self.fmu_logging = system, algorithm, fmu_logging
        self.exchange = EXCHANGES[algorithm]()
        self.step_size = require_positive("step_size", step_size)
        self.start_time, self.step_index = 0.0, 0
        self.elements = {e.name: e for e in system.elements}
        self._slaves: dict[str, _Slave] = {}
        self.slaves: list[_Slave] = []  # in the order they step
        self._compiled = None  # the compiled step, once the FMUs are instantiated (if the kernel carries them)
        self._folders: list[str] = []
        self.ended: HorizonEnd | None = None
        self._plan_columns(dict(inputs or {}))
        self._plan_exchange()
        self.row: list = [0.0] * len(self.columns)

    # -- planning (no FMU loaded) ---------------------------------------------------------------------
    def _plan_columns(self, inputs: dict[str, object]) -> None:
        """Columns: time, external inputs, every recordable output; and who sets each driven input."""
        linked = {(link.target.element, link.target.name): link for link in self.system.links}
        self.overridden: list = []  # connections an external input replaces
        self.columns: list[Column] = [Column("time", "s")]
        self.signals: list[tuple[int, Callable[[float], float], Callable]] = []
        self.sources: dict[tuple[str, str], int] = {}  # driven input -> row column
        for name, system_input in self.system.system_inputs.items():
            if name not in inputs and system_input.value is not None and system_input.targets:
                inputs[name] = system_input.value
            elif name not in inputs and not all(t.path in inputs for t in system_input.targets):
                logger.warning("system input %r is not driven: %s keep their start values", name,
                               ", ".join(t.path for t in system_input.targets))
        for name, source in inputs.items():
            targets = self._input_targets(name, linked)
            types = {TRANSPORT.get(t.type, t.type) for t in targets}
            if len(types) > 1:
                raise TypeMismatchError(f"external input {name!r} drives inputs of different types: "
                                        f"{', '.join(f'{t.path} ({t.type})' for t in targets)}")
            kind = types.pop() if types else "Real"
            if kind not in _CONVERT:
                raise UnsupportedFeatureError(f"external input {name!r}: {kind} inputs cannot be driven")
            unit = self.system.system_inputs[name].unit if name in self.system.system_inputs else None
            column = len(self.columns)
            self.columns.append(Column(name, unit or (targets[0].unit if targets else None), kind))
            self.signals.append((column, as_signal(source, name=name), _CONVERT[kind]))
            for target in targets:
                self.sources[(target.element, target.name)] = column
        self.output_columns: dict[tuple[str, str], int] = {}
        for element in self.system.elements:
            for output in element.outputs:
                variable = element.variables[output]
                kind = TRANSPORT.get(variable.type)
                if kind not in _CTYPES:
                    logger.debug("%s.%s: %s outputs are not recorded", element.name, output, variable.type)
                    continue
                self.output_columns[(element.name, output)] = len(self.columns)
                self.columns.append(Column(f"{element.name}.{output}", variable_unit(variable), kind))
        self.transformations: dict[tuple[str, str], LinearTransformation] = {}
        replaced = {id(link) for link in self.overridden}
        self.links = tuple(link for link in self.system.links if id(link) not in replaced)
        for link in self.links:
            key = (link.source.element, link.source.name)
            if key not in self.output_columns:
                raise UnsupportedFeatureError(f"connection {link.source.path} -> {link.target.path}: "
                                              f"{link.source.type} connections are not supported")
            self.sources[(link.target.element, link.target.name)] = self.output_columns[key]
            if link.transformation is not None:
                self.transformations[(link.target.element, link.target.name)] = link.transformation
        self.columns = tuple(self.columns)

    def _input_targets(self, name: str, linked: Mapping) -> list:
        if name in self.system.system_inputs:
            return list(self.system.system_inputs[name].targets)
        element_name, _, variable_name = name.rpartition(".")
        element = self.elements.get(element_name)
        if element is None or variable_name not in element.variables:
            known = [*self.system.system_inputs, *(f"{e.name}.{v}" for e in self.system.elements
                                                   for v in e.variables if e.variables[v].causality == "input")]
            raise UnknownConnectorError(f"external input {name!r}: not an input of an element nor a system input "
                                        f"connector (inputs: {', '.join(known) or 'none'})")
        variable = element.variables[variable_name]
        if variable.causality != "input":
            raise CausalityError(f"external input {name!r}: {name} is of causality {variable.causality}, not an input "
                                 "(set parameters with parameter overrides)")
        if (element_name, variable_name) in linked:
            link = linked[(element_name, variable_name)]
            logger.info("external input %r replaces the connection %s -> %s", name, link.source.path, link.target.path)
            self.overridden.append(link)
        return [element.port(variable_name)]

    def _plan_exchange(self) -> None:
        names = [e.name for e in self.system.elements]
        outputs = {e: [o for (el, o) in self.output_columns if el == e] for e in names}
        inputs = {e: [i for (el, i) in self.sources if el == e] for e in names}
        links = [((link.source.element, link.source.name), (link.target.element, link.target.name))
                 for link in self.links]
        feedthrough = {e.name: e.feedthrough for e in self.system.elements}
        self.plan: tuple[Action, ...] = self.exchange.plan(names, outputs, inputs, links, feedthrough)

    @property
    def order(self) -> list[str]:
        """What happens in one communication step, as text (``set A.u``, ``get A.y, A.z``, ``doStep all``)."""
        return self.exchange.order(self.plan)

    # -- running -----------------------------------------------------------------------------------
    @property
    def engine(self) -> str:
        """Who makes the step's calls: ``"C"``, the compiled kernel (:mod:`.compiled_exchange`), or ``"Python"``."""
        return "C" if self._compiled is not None else "Python"

    @property
    def time(self) -> float:
        """The current communication point [s]."""
        return self.start_time + self.step_index * self.step_size

    def instantiate(self) -> None:
        """Extract, load and instantiate every FMU, and set its start values."""
        for element in self.system.elements:
            source = element.source
            once = element.model_description.coSimulation.canBeInstantiatedOnlyOncePerProcess
            if source.is_dir():
                folder = str(source)
            else:
                try:
                    folder = extract(str(source)) if once else fmu_folders.extracted(source)
                except Exception as exc:
                    raise FmuLoadError(f"element {element.name!r}: cannot extract {source}: {exc}") from None
                if once:
                    self._folders.append(folder)
            slave = _slave(element, folder, self.fmu_logging)
            self._slaves[element.name] = slave
            slave.instantiate()
            self._apply_start_values(slave)
        self._build_transfers()

    def _apply_start_values(self, slave: _Slave) -> None:
        variables = slave.element.variables
        for name, value in slave.element.start_values.items():
            variable = variables[name]
            try:
                slave.set_start(variable, value)
            except FMICallException as exc:
                raise self._failure(slave, exc, f"for {name} = {shown(value)} from "
                                                f"{slave.element.origins.get(name, '?')}") from None
            logger.debug("%s.%s = %r (%s)", slave.name, name, value, slave.element.origins.get(name, "?"))

    def _build_transfers(self) -> None:
        immediate = self.exchange.immediate
        self.sweep: list[_Transfer] = []
        for action in self.plan:
            slave = self._slaves[action.element]
            by_type: dict[tuple[int, str], list[str]] = {}  # (transport order, FMU type) -> names
            for name in action.variables:
                type_ = slave.element.variables[name].type
                type_ = type_ if slave.fmi == 3 else TRANSPORT[type_]
                by_type.setdefault((_ORDER.index(TRANSPORT[type_]), type_), []).append(name)
            for _, kind in sorted(by_type):
                names = tuple(by_type[(_, kind)])
                table = self.output_columns if action.kind == "get" else self.sources
                columns = tuple(table[(action.element, n)] for n in names)
                transformations = tuple(self.transformations.get((action.element, n)) for n in names) \
                    if action.kind == "set" else ()
                transfer = _Transfer(slave, action.kind, kind, names, columns, immediate, transformations)
                transfer.bind()
                self.sweep.append(transfer)
        self.sets = [t for t in self.sweep if t.kind == "set"]
        self.gets = [t for t in self.sweep if t.kind == "get"]
        self.slaves = list(self._slaves.values())
        integer_columns = tuple(c for c, column in enumerate(self.columns) if column.type != "Real")
        self._signal_columns = (0, *(column for column, _, _ in self.signals))  # what the step writes from Python
        integer_inputs = [self.columns[c].name for c, _, _ in self.signals if self.columns[c].type == "Integer"]
        self._compiled = compiled_step(self.slaves, *self.exchange.programs(self), len(self.columns), integer_columns,
                                       integer_inputs)

    def _update_signals(self) -> None:
        t, row = self.time, self.row
        row[0] = t
        for column, signal, convert in self.signals:
            row[column] = convert(signal(t))

    def run(self, transfers: list[_Transfer]) -> None:
        """Carry out ``transfers`` (some of :attr:`sweep`) on the row."""
        transfer = None
        try:
            for transfer in transfers:
                transfer.run(self.row)
        except FMICallException as exc:
            raise self._failure(transfer.slave, exc, f"for {', '.join(transfer.names)}") from None

    def _call_all(self, name: str) -> None:
        slave = None
        try:
            for slave in self.slaves:
                getattr(slave.fmu, name)()
        except FMICallException as exc:
            raise self._failure(slave, exc) from None

    def initialize(self, start_time: float = 0.0, stop_time: float | None = None) -> None:
        """setupExperiment, enter initialisation, propagate, exit initialisation: ``row`` holds t0."""
        self.start_time, self.step_index = float(start_time), 0
        slave = None
        try:
            for slave in self.slaves:
                slave.setup_experiment(self.start_time, stop_time)
            for slave in self.slaves:  # as FMI 2.0 hosts do: every setupExperiment first, then initialisation
                slave.enter_initialization_mode()
        except FMICallException as exc:
            raise self._failure(slave, exc) from None
        for slave in self.slaves:
            slave.state = "initialization"
        self._update_signals()
        self.exchange.initialise(self)
        self._call_all("exitInitializationMode")
        self._set_running()
        self.exchange.exchange(self)
        if self._compiled is not None:
            self._compiled.load_row(self.row)
        logger.info("initialised %d FMUs at t = %g s (%s)", len(self.slaves), self.start_time, self.algorithm)

    def load_sets(self) -> None:
        """Load every set's value from the row, for the next :meth:`run` of :attr:`sets` (jacobi)."""
        row = self.row
        for transfer in self.sets:
            transfer.load(row)

    def _set_running(self) -> None:
        for slave in self.slaves:
            slave.state = "running"

    def step(self) -> None:
        """Advance every FMU by one communication step: ``row`` then holds the values at the new ``time``.

        An FMU that ends its own horizon (fmi2Discard from doStep, then fmi2Terminated true) sets
        :attr:`ended`; if its last successful time is short of the step's end, the step is not taken
        and ``row`` keeps the values at the current ``time``.

        The step's calls are made by the compiled kernel where there is one (:mod:`.compiled_exchange`), else
        from Python; either way the same calls with the same values, and the same handling of their outcome.
        """
        t, dt = self.time, self.step_size
        compiled = self._compiled
        if compiled is None:
            self.exchange.before_steps(self)
        else:
            self._run_compiled(compiled.before)
        first = 0
        while first < len(self.slaves):
            index, failure, terminated_at = self._do_steps(first, t, dt)
            if index < 0:
                break
            slave = self.slaves[index]
            self.ended = (self._horizon_end(slave, failure, t + dt) if failure is not None
                          else self._terminated(slave, terminated_at, t + dt))
            if not self.ended.step_completed:
                return
            first = index + 1
        self.step_index += 1
        self._update_signals()
        if compiled is None:
            self.exchange.exchange(self)
            return
        for column in self._signal_columns:
            compiled.row[column] = self.row[column]
        try:
            self._run_compiled(compiled.after)
        finally:  # a call that fails leaves what was read before it, as the Python exchange does
            compiled.store_row(self.row)

    def _do_steps(self, first: int, t: float, dt: float) -> tuple[int, FMICallException | None, float | None]:
        """doStep every slave from index ``first``: (-1, None, None), or the index of the first that did not step
        cleanly, with its failure, or (FMI 3.0) the last successful time of its terminateSimulation."""
        if self._compiled is not None:
            index, status, last = self._compiled.do_steps(first, t, dt)
            if index < 0 or status <= fmi2Warning:
                return index, None, last
            return index, FMICallException(function=f"fmi{self.slaves[index].fmi}DoStep", status=status), None
        clock = time.perf_counter
        for index in range(first, len(self.slaves)):
            slave = self.slaves[index]
            started = clock()
            try:
                terminated_at = slave.do_step(t, dt)
            except FMICallException as exc:
                return index, exc, None
            finally:
                slave.step_time += clock() - started
            if terminated_at is not None:
                return index, None, terminated_at
        return -1, None, None

    def _run_compiled(self, program) -> None:
        """Carry out a compiled program; its failed call raised as :meth:`run` raises it."""
        transfer, status = self._compiled.run(program)
        if transfer is not None:
            raise self._failure(transfer.slave, FMICallException(function=transfer.name, status=status),
                                f"for {', '.join(transfer.names)}")

    def _horizon_end(self, slave: _Slave, exc: FMICallException, step_end: float) -> "HorizonEnd":
        """A discarded doStep is the end of the FMU's horizon if it says it has terminated (FMI 2.0,
        fmi2GetBooleanStatus(fmi2Terminated)); anything else is a failure."""
        if exc.status != fmi2Discard or slave.fmi == 3:  # FMI 3.0 ends a horizon with terminateSimulation
            raise self._failure(slave, exc) from None
        terminated, reached = fmi2Boolean(0), fmi2Real(0.0)
        try:
            slave.fmu.fmi2GetBooleanStatus(slave.component, _FMI2_TERMINATED, ctypes.byref(terminated))
        except FMICallException:
            terminated.value = 0
        if not terminated.value:
            raise self._failure(slave, exc) from None
        try:
            slave.fmu.fmi2GetRealStatus(slave.component, _FMI2_LAST_SUCCESSFUL_TIME, ctypes.byref(reached))
            last = reached.value
        except FMICallException:  # unknown: the step is not taken
            last = self.time
        ended = HorizonEnd(slave.name, last, abs(last - step_end) <= 1e-9 * max(1.0, abs(step_end)),
                           list(slave.messages))
        logger.info("%s", ended.note)  # not a failure: the run's summary carries the note
        return ended

    def _terminated(self, slave: _Slave, last: float, step_end: float) -> HorizonEnd:
        """FMI 3.0: fmi3DoStep asked to terminate the simulation, having reached ``last``."""
        ended = HorizonEnd(slave.name, last, abs(last - step_end) <= 1e-9 * max(1.0, abs(step_end)),
                           list(slave.messages), "terminateSimulation from fmi3DoStep")
        logger.info("%s", ended.note)  # not a failure: the run's summary carries the note
        return ended

    def refresh(self) -> None:
        """Read the external inputs again at the current time and redo the exchange there (an input that
        changed without time passing, e.g. a command from hardware); ``row`` then holds the new values."""
        self._update_signals()
        self.exchange.refresh(self)
        if self._compiled is not None:
            self._compiled.load_row(self.row)

    def _failure(self, slave: _Slave, exc: FMICallException, context: str = "") -> FmuCallError:
        slave.state = "fatal" if exc.status >= 4 else "error"
        others = [m for m in slave.messages if m not in slave.reasons]  # the cause first, then what came before
        return FmuCallError(slave.name, exc.function, exc.status, self.time, [*slave.reasons, *others], context)

    def timing(self) -> dict[str, dict]:
        """Per element: its FMU file and the wall time spent in its doStep calls [s]."""
        steps = max(self.step_index, 1)
        compiled = self._compiled
        seconds = {slave.name: slave.step_time + (compiled.seconds(index) if compiled is not None else 0.0)
                   for index, slave in enumerate(self.slaves)}
        return {name: {"fmu": slave.element.source.name, "do_step_total_s": seconds.get(name, 0.0),
                       "do_step_mean_us": seconds.get(name, 0.0) / steps * 1e6} for name, slave in self._slaves.items()}

    def close(self) -> None:
        """Terminate and free every instance that FMI allows to, then remove the extracted FMUs."""
        # after fmi2Fatal FMI allows no further call to any instance of that FMU: of its library, its folder
        fatal = {s.folder for s in self._slaves.values() if s.state == "fatal"}
        for slave in reversed(list(self._slaves.values())):
            if slave.state in ("loaded", "freed") or slave.folder in fatal:
                if slave.state == "fatal" or slave.folder in fatal:
                    logger.info("%s: not freed (fmi2Fatal: FMI allows no further call)", slave.name)
                continue
            try:
                if slave.state == "running":
                    slave.fmu.terminate()
                slave.fmu.freeInstance()
            except Exception as exc:  # cleanup must not hide the error that got us here
                logger.warning("%s: terminate/free failed: %s%s", slave.name, exc,
                               f"; {slave.messages[-1]}" if slave.messages else "")
            slave.state = "freed"
        for folder in fatal:  # the next run extracts it anew
            fmu_folders.forget(folder)
        for folder in self._folders:  # a library still mapped after fmi2Fatal survives its files' removal
            shutil.rmtree(folder, ignore_errors=True)
        self._folders.clear()

    def __enter__(self) -> "Master":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
