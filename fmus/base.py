"""The base of every nfal FMU slave: :class:`NfalSlave`, a thin layer over pythonfmu's ``Fmi2Slave``.

pythonfmu 0.7.0 leaves gaps that the contract (docs/cosimulation.md) needs filled. This module fills
them in one place, so that each slave (``fmus/slow_plant.py``, ``fmus/controller.py``, ...) stays a
thin adapter over :mod:`nfal.models`:

* **Declarations with units.** :meth:`NfalSlave.add_parameter`, :meth:`~NfalSlave.add_input` and
  :meth:`~NfalSlave.add_output` declare a variable with its unit, description, causality,
  variability and start value; :meth:`~NfalSlave.to_xml` writes ``<UnitDefinitions>`` (SI base-unit
  exponents, :data:`UNITS`), ``unit=`` on every Real, ``<ModelStructure><Outputs>`` with
  ``dependencies``/``dependenciesKind`` and ``<InitialUnknowns>``, so that
  ``fmpy.validation.validate_fmu`` finds no problem.
* **Direct feedthrough.** An output declared with a ``getter`` and ``depends_on=("an_input", ...)``
  is computed when it is read, from the current inputs and state; an output without a getter reads
  the attribute of the same name, which the slave sets from its state (no dependencies).
* **Errors.** Every entry point the FMU runtime calls (setters, getters, initialisation, ``do_step``,
  FMU state) is guarded. Inside the runtime (the instance was passed a ``logger``) an exception
  becomes :class:`SlaveCallError` ``"<instance>: <reason> (in <call>)"``, which our patched runtime
  (``fmus/runtime/``, ``fmus/export_runtime.py``) logs once with status fmi2Error and answers with
  **fmi2Error**; the instance stays usable and can be freed. As a Python object (tests, the rig
  emulator) the reason is logged (``logging`` and ``self.log``) and the original exception re-raised.
* **Parameters checked at the end of initialisation.** Setters only store (with type coercion and,
  for Real inputs, a finiteness check); :meth:`setup` (abstract) validates and builds the models in
  ``exit_initialization_mode``. A ``fixed`` parameter set after initialisation is an error.
* **The value cache.** In our runtime a step's gets and sets of Real and Boolean inputs and outputs do not enter
  Python: the slave shares their values with the runtime in a buffer (``_value_cache_layout``; docs/cosimulation.md,
  "the value cache"), and a slave may give the runtime a compiled core that steps it there
  (``_value_cache_core``: the ReynoldsPlant's free flight).
* **FMU state.** ``_get_fmu_state``/``_set_fmu_state`` save every variable, the time and whatever
  :meth:`get_internal_state` returns (plant state, controller state, RNG state: JSON-ready values);
  states serialize to JSON bytes (``canGetAndSetFMUstate`` and ``canSerializeFMUstate`` are true).
* **Sampled blocks.** :class:`SampleClock` (steps on a whole number of sample periods).

What the rig's blocks share on top of this (the rig parameters, ``calibration``, the plant interface and the
models built from them) is :class:`~nfal.fmus.rig_contract.RigSlave`'s.

Writing a slave
---------------
Subclass :class:`NfalSlave` (the builder picks the concrete class), declare in ``__init__``,
implement :meth:`setup` and :meth:`step`::

    class Gain(NfalSlave):
        description = "y = k u"

        def __init__(self, **kwargs):
            super().__init__(**kwargs)
            self.add_parameter("k", 2.0, unit="1", description="gain")
            self.add_input("u", 0.0, unit="m", description="input")
            self.add_output("y", unit="m", description="k u", depends_on=("u",), getter=lambda: self.k * self.u)
            self.add_output("y_last", unit="m", description="y at the last step")   # reads self.y_last
            self.y_last = 0.0

        def setup(self):                 # exit_initialization_mode: validate, build models
            require_positive("k", self.k)

        def step(self, current_time, step_size):   # commit state over [t, t + dt]
            self.y_last = self.k * self.u

        def get_internal_state(self):    # optional: JSON-ready internal state
            return {}

The values live in attributes of the same names (``self.k``, ``self.u``); a computed output's getter
must not change state (it may be read any number of times).
"""

from __future__ import annotations

import abc
import contextlib
import copy
import json
import logging
import math
import os
from typing import Any, Callable, Iterable
from xml.etree.ElementTree import Element, SubElement

from pythonfmu import Fmi2Slave
from pythonfmu.default_experiment import DefaultExperiment
from pythonfmu.enums import Fmi2Causality, Fmi2Status, Fmi2Variability
from pythonfmu.variables import Boolean, Integer, Real, ScalarVariable, String

from nfal import __version__
from nfal.errors import (FmuStateError, InvalidParameterError, SlaveCallError, require_finite,
                         require_positive)
from nfal.models import clock_kernels

logger = logging.getLogger(__name__)

__all__ = ["NfalSlave", "SampleClock", "FmuStateError", "SlaveCallError", "UNITS", "DefaultExperiment",
           "SAMPLE_TOLERANCE"]

#: SI base-unit exponents of every unit an nfal FMU declares (FMI 2.0 ``<BaseUnit>`` attributes).
#: "1" is a dimensionless number. Add to it (before building) for a new unit.
UNITS: dict[str, dict[str, int]] = {
    "1": {},
    "m": {"m": 1},
    "m/s": {"m": 1, "s": -1},
    "m/s2": {"m": 1, "s": -2},
    "s": {"s": 1},
    "Hz": {"s": -1},
    "rad": {"rad": 1},
    "rad/s": {"rad": 1, "s": -1},
    "kg": {"kg": 1},
    "N": {"kg": 1, "m": 1, "s": -2},
    "Pa": {"kg": 1, "m": -1, "s": -2},
    "Pa.s": {"kg": 1, "m": -1, "s": -1},
    "V": {"kg": 1, "m": 2, "s": -3, "A": -1},
    "m/V": {"kg": -1, "m": -1, "s": 3, "A": 1},
}

#: Relative tolerance of "a whole number of sample periods from the start" (contract).
SAMPLE_TOLERANCE = 1e-9

#: The runtime's value cache buffer (fmus/value_cache/nfal_value_cache.hpp, the same numbers): 1 while inputs set in
#: the runtime wait for the slave; 1 while the outputs computed from inputs are out of date; 1 while the state's
#: outputs and the time (CORE_TIME) that a compiled core stepped to are newer than the slave's; 1 while the slave holds
#: every step for its Python (not initialised), whatever its core; then the variables.
INPUTS_WAITING, COMPUTED_STALE, CORE_STEPPED, CORE_TIME, CORE_HELD, FIRST_SLOT = range(6)
#: ``NFAL_VALUE_CACHE=off`` in the environment: every call goes to the slave's Python (the cache's own baseline, and a
#: way to rule it out).
VALUE_CACHE_ENV = "NFAL_VALUE_CACHE"

_PY_TYPES = {float: Real, int: Integer, bool: Boolean, str: String}
_COERCE = {Real: float, Integer: int, Boolean: bool, String: str}



class SampleClock:
    """Sample instants t0 + k T of a sampled block (Controller, SensorChain, PLL), per the contract.

    A communication point is a sample instant when it lies a whole number of periods from the start
    time, within ``SAMPLE_TOLERANCE`` relative (to the larger of T and t - t0); between instants the
    block holds its outputs. A communication step longer than the period is an error.

    Parameters
    ----------
    period_s : float
        Sample period T [s].
    start_time_s : float
        t0 [s], the experiment's start time.
    """

    def __init__(self, period_s: float, start_time_s: float = 0.0) -> None:
        self.period_s = require_positive("sample period", period_s)
        self.start_time_s = float(start_time_s)
        self._last: tuple[float, int | None] = (math.nan, None)  # (time, its index): a step asks about one time often
        self._checked_step = math.nan  # the step size check_step last accepted

    def index(self, time_s: float) -> int | None:
        """k if ``time_s`` is the sample instant t0 + k T (k >= 0), else None."""
        if time_s == self._last[0]:
            return self._last[1]
        k = clock_kernels.sample_index(float(time_s), self.start_time_s, self.period_s, SAMPLE_TOLERANCE)
        index = None if k < 0 else k
        self._last = (time_s, index)
        return index

    def is_sample(self, time_s: float) -> bool:
        """Whether ``time_s`` [s] is a sample instant."""
        return self.index(time_s) is not None

    def check_step(self, step_size_s: float) -> None:
        """Raise :class:`InvalidParameterError` unless a communication step divides the period.

        A longer step would skip samples; one that does not divide the period would meet the sample
        instants only at common multiples and silently lower the sample rate (0.3 ms on 0.5 ms: 667 Hz).
        """
        if step_size_s == self._checked_step:
            return
        if not clock_kernels.divides(self.period_s, step_size_s, SAMPLE_TOLERANCE):
            raise InvalidParameterError("communication step size", step_size_s,
                                        f"the sample period {self.period_s:.6g} s divided by a whole number "
                                        f"(e.g. {self.period_s:.6g} s or {self.period_s / 2:.6g} s)")
        self._checked_step = step_size_s


class _Declaration:
    """What NfalSlave knows about a variable beyond pythonfmu's ScalarVariable."""

    __slots__ = ("variable", "unit", "depends_on", "computed", "tunable")

    def __init__(self, variable: ScalarVariable, unit: str | None, depends_on: tuple[str, ...], computed: bool,
                 tunable: bool) -> None:
        self.variable, self.unit, self.depends_on = variable, unit, depends_on
        self.computed, self.tunable = computed, tunable


class NfalSlave(Fmi2Slave):
    """Abstract base of the nfal FMU slaves (see the module docstring for the whole contract).

    Subclasses declare variables in ``__init__`` with :meth:`add_parameter`, :meth:`add_input` and
    :meth:`add_output`, and implement :meth:`setup` (end of initialisation) and :meth:`step`
    (one communication step); optionally :meth:`get_internal_state`/:meth:`set_internal_state`.

    Attributes
    ----------
    time : float
        The current communication point [s]: the start time, then t + dt after each step.
    initialized : bool
        True once :meth:`setup` has run (``exit_initialization_mode``).
    """

    #: Whether the FMU saves, restores and serialises its state (modelDescription.xml's canGetAndSetFMUstate
    #: and canSerializeFMUstate); a slave that cannot be rewound (hardware) says False.
    CAN_SAVE_STATE = True

    author = "nfal"
    license = "MIT"

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.version = __version__
        self.modelName = type(self).__name__
        # pythonfmu's C wrapper passes the FMI logger; a slave made in Python (tests) gets none.
        self._in_wrapper = "logger" in kwargs
        self._declarations: dict[str, _Declaration] = {}
        self.time = 0.0
        self.start_time = 0.0
        #: the stop time the host declared in setupExperiment (FMI 2.0), None when it declared none
        self.stop_time: float | None = None
        self.initialized = False
        self._in_initialization = False
        self._settings_changed = True
        # each variable type's getters and setters by value reference: the exchange's hot path (_get, _set)
        self._getters: dict[type, dict[int, Callable[[], Any]]] = {kind: {} for kind in _COERCE}
        self._setters: dict[type, dict[int, Callable[[Any], None]]] = {kind: {} for kind in _COERCE}
        #: the runtime's value cache (:meth:`_bind_value_cache`): its buffer, None until bound or outside the runtime
        self._value_cache = None
        self._core_data = None  # a compiled core's data (_value_cache_core), which the slave keeps alive

    # --- declarations -------------------------------------------------------------------------------
    def add_parameter(self, name: str, start: float | int | bool | str, *, unit: str | None = None,
                      description: str = "", tunable: bool = False) -> ScalarVariable:
        """Declare a parameter held in ``self.<name>`` (type from ``start``: write ``0.0`` for a Real).

        ``fixed`` unless ``tunable``; its value is checked by :meth:`setup` when initialisation ends.
        """
        variability = Fmi2Variability.tunable if tunable else Fmi2Variability.fixed
        return self._declare(name, start, Fmi2Causality.parameter, variability, unit, description, (), None, tunable)

    def add_input(self, name: str, start: float | int | bool | str, *, unit: str | None = None,
                  description: str = "") -> ScalarVariable:
        """Declare an input held in ``self.<name>``; a Real input must be finite (checked when set)."""
        kind = _kind_of(name, start)
        variability = Fmi2Variability.continuous if kind is Real else Fmi2Variability.discrete
        return self._declare(name, start, Fmi2Causality.input, variability, unit, description, (), None, False)

    def add_output(self, name: str, *, kind: type = float, unit: str | None = None, description: str = "",
                   depends_on: Iterable[str] = (), getter: Callable[[], Any] | None = None) -> ScalarVariable:
        """Declare an output of Python type ``kind`` (float, bool, int, str).

        Without ``getter`` it reads ``self.<name>``, which the slave keeps from its state: it then
        depends on no input (``depends_on`` must be empty). With ``getter`` it is *computed on read*
        (``getter()`` from the current inputs and state, without side effects) and ``depends_on``
        names the inputs it feeds through from (ModelStructure ``dependencies``).
        """
        depends_on = tuple(depends_on)
        if getter is None and depends_on:
            raise InvalidParameterError("depends_on", depends_on,
                                        "empty for an output read from an attribute (give a getter)")
        for source in depends_on:
            declared = self._declarations.get(source)
            if declared is None or declared.variable.causality != Fmi2Causality.input:
                raise InvalidParameterError("depends_on", source, "the name of an input declared before the output")
        if kind not in _PY_TYPES:
            raise InvalidParameterError("kind", kind, "float, int, bool or str")
        variability = Fmi2Variability.continuous if kind is float else Fmi2Variability.discrete
        return self._declare(name, kind, Fmi2Causality.output, variability, unit, description, depends_on, getter,
                             False)

    def _declare(self, name, start, causality, variability, unit, description, depends_on, getter,
                 tunable) -> ScalarVariable:
        if name in self._declarations:
            raise InvalidParameterError("name", name, "a variable name not declared before")
        if unit is not None and unit not in UNITS:
            raise InvalidParameterError("unit", unit, f"one of {sorted(UNITS)} (or add it to UNITS)")
        if causality == Fmi2Causality.output:
            cls = _PY_TYPES[start]
            if getter is None and not hasattr(self, name):
                setattr(self, name, _COERCE[cls]())
            variable = cls(name, causality=causality, variability=variability, description=description or None,
                           getter=getter)
        else:
            cls = _kind_of(name, start)
            setattr(self, name, _COERCE[cls](start))
            variable = cls(name, causality=causality, variability=variability, description=description or None,
                           start=_COERCE[cls](start))
        if unit is not None and cls is not Real:
            raise InvalidParameterError("unit", unit, f"None for the non-Real variable {name}")
        self.register_variable(variable, nested=False)
        variable.setter = self._make_setter(name, cls, causality, tunable)
        self._getters[cls][variable.value_reference] = variable.getter
        self._setters[cls][variable.value_reference] = variable.setter
        self._declarations[name] = _Declaration(variable, unit, depends_on, getter is not None, tunable)
        return variable

    def _make_setter(self, name: str, cls: type, causality, tunable: bool) -> Callable[[Any], None]:
        if causality == Fmi2Causality.output:
            def refuse(value) -> None:
                raise InvalidParameterError(name, value, "not set: it is an output")
            return refuse
        coerce = _COERCE[cls]
        check_finite = cls is Real and causality == Fmi2Causality.input
        fixed = causality == Fmi2Causality.parameter and not tunable

        def setter(value) -> None:
            value = coerce(value)
            if check_finite and not math.isfinite(value):
                raise InvalidParameterError(name, value, "a finite number")
            if fixed and self.initialized:
                raise InvalidParameterError(name, value, "unchanged after initialisation (a fixed parameter, now "
                                            f"{getattr(self, name)!r})")
            setattr(self, name, value)
            self._settings_changed = True
        return setter

    # --- as a Python object (tests, the rig emulator) ------------------------------------------------
    def value(self, name: str) -> Any:
        """A declared variable's value as an FMI getter returns it (a computed output is computed now)."""
        return self._declarations[name].variable.getter()

    def set_value(self, name: str, value: Any) -> None:
        """Set a declared variable as an FMI setter does (coerced and checked)."""
        self._declarations[name].variable.setter(value)

    # --- the slave's part ----------------------------------------------------------------------------
    @abc.abstractmethod
    def setup(self) -> None:
        """End of initialisation: validate the parameters (raise on bad ones) and build the models."""

    @abc.abstractmethod
    def step(self, current_time: float, step_size: float) -> None:
        """Advance the state from ``current_time`` by ``step_size`` [s] with the inputs held (commit)."""

    def get_internal_state(self) -> dict:
        """State beyond the declared variables, as JSON-ready values (floats, lists, dicts, strings)."""
        return {}

    def set_internal_state(self, state: dict) -> None:
        """Restore what :meth:`get_internal_state` returned."""

    # --- FMI entry points (called by pythonfmu's C wrapper), guarded -----------------------------------
    def _guard(self, what: str, function: Callable, *args):
        try:
            return function(*args)
        except Exception as exc:  # noqa: BLE001 - every error must reach the master as a logged FMI status
            self._fail(what, exc)
            raise

    def _fail(self, what: str, exc: BaseException) -> None:
        """Say why a call fails: in the runtime, raise SlaveCallError (logged once, fmi2Error); else log."""
        error = SlaveCallError(self.instance_name, what, str(exc) or type(exc).__name__)
        if self._in_wrapper:
            raise error from exc
        logger.error("%s", error)
        self.log(str(error), Fmi2Status.error)

    def setup_experiment(self, start_time: float, stop_time=None, tolerance=None) -> None:
        def run():  # the start anchors every sample clock; the stop only plans (nothing fails on a strange one)
            self.start_time = self.time = require_finite("start time", start_time)
            self.stop_time = None if stop_time is None else float(stop_time)
        self._guard("setup_experiment", run)

    def enter_initialization_mode(self) -> None:
        self._in_initialization = True

    def _read(self, what: str, read, vrs):
        """Outputs read in initialisation mode are those of a provisional :meth:`setup` with the values set
        so far (the initial state: the plant at initial_height, the controller's bumpless command), so a
        master that propagates outputs before the first step hands on consistent values, not zeros."""
        if self._in_initialization and self._settings_changed:
            self._guard("the set-up from the parameters", self.setup)
            self._settings_changed = False
        return self._guard(what, read, vrs)

    def exit_initialization_mode(self) -> None:
        def run():
            self.setup()
            self.initialized = True
            self._in_initialization = False
        self._guard("exit_initialization_mode, the set-up from the parameters", run)

    def do_step(self, current_time: float, step_size: float) -> bool:
        cache = self._value_cache
        try:  # not through _guard: the hot path builds no closure and no message unless it fails
            if cache is not None:
                self._take_from_cache()
            if not self.initialized:
                raise InvalidParameterError("doStep", current_time, "called after initialisation ends")
            if not (math.isfinite(step_size) and step_size > 0):
                raise InvalidParameterError("communication step size", step_size, "a finite number > 0 s")
            self.step(float(current_time), float(step_size))
            self.time = float(current_time) + float(step_size)
            if cache is not None:  # the state's outputs; the computed ones wait for a read (the runtime knows)
                self._write_state_outputs()
                self._sync_core()
            return True
        except Exception as exc:  # noqa: BLE001 - every error must reach the master as a logged FMI status
            if cache is not None:  # what the failed step left, as far as it reads: the error is the step's
                with contextlib.suppress(Exception):
                    self._write_state_outputs()
            self._fail(f"doStep at t = {current_time:.9g} s", exc)
            raise

    def terminate(self) -> None:
        pass

    # Every step's gets and sets go through _get and _set: the declared getters and setters by value reference, no
    # closure, no type test per value (0.2-0.6 us less a call than pythonfmu's loop behind _guard). What they cannot
    # answer (a value reference of another type, a setter or getter that raises, initialisation's provisional set-up)
    # goes the checked way, pythonfmu's (``_checked``), which raises saying why: getters have no side effects, and a set
    # repeated from the first value sets the same values again.
    def _get(self, kind: type, vrs, what: str) -> list:
        if not self._in_initialization:
            try:
                getters, convert = self._getters[kind], _COERCE[kind]
                cache = self._value_cache
                if cache is not None:  # the runtime asks: computed outputs out of date, or not its variables
                    self._take_from_cache()  # what waits for the slave
                    if cache[COMPUTED_STALE]:  # each computed once, not again for a read of another variable
                        self._write_computed()
                    slots = self._computed_slots[kind]
                    return [convert(cache[slots[vr]]) if vr in slots else convert(getters[vr]()) for vr in vrs]
                return [convert(getters[vr]()) for vr in vrs]
            except Exception:  # noqa: BLE001 - answered by the checked path
                pass
        return self._read(what, self._checked(what), vrs)

    def _set(self, kind: type, vrs, values, what: str) -> None:
        if self._value_cache is not None:
            self._take_from_cache()  # inputs set before these, by the runtime; the state its core stepped
        try:
            setters = self._setters[kind]
            for vr, value in zip(vrs, values):
                setters[vr](value)
        except Exception:  # noqa: BLE001 - answered by the checked path
            self._guard(what, self._checked(what), vrs, values)
        finally:
            if self._value_cache is not None:  # what a set changes: inputs, and the computed outputs at their read
                self._write_inputs()
                self._value_cache[COMPUTED_STALE] = 1.0

    def _checked(self, what: str) -> Callable:
        """pythonfmu's own ``getReal`` ... ``setString`` (the checked way), looked up only when it is needed."""
        return getattr(super(), f"{what[:3]}_{what[3:].lower()}")

    # --- the runtime's value cache -----------------------------------------------------------------------
    # Our runtimes (fmus/runtime/, fmus/runtime3/; the ValueCache of fmus/value_cache/) answer the gets and sets of
    # every step from a buffer of the Real and Boolean inputs and outputs that they bind at the end of initialisation,
    # without entering Python (its slots: INPUTS_WAITING ... FIRST_SLOT). Every call that reads the inputs takes those
    # set in the runtime first. After a step the slave writes its state's outputs. While the outputs computed from
    # inputs are out of date the runtime sends their next read here, which writes them all. A slave with a compiled
    # core (_value_cache_core) may have the runtime step it on the buffer; every call first takes the state and the
    # time the core stepped to.
    def _value_cache_layout(self) -> list[tuple[int, bool, int]] | None:
        """(value reference, is Boolean, role: 0 input, 1 output of the state, 2 output computed from inputs) of the
        variables the runtime keeps, slot FIRST_SLOT onwards in this order; None: no cache (VALUE_CACHE_ENV)."""
        if os.environ.get(VALUE_CACHE_ENV, "").lower() == "off":
            return None
        return [(d.variable.value_reference, type(d.variable) is Boolean, role)
                for d, role in self._cached_declarations()]

    def _cached_declarations(self) -> list[tuple[_Declaration, int]]:
        cached = []
        for declaration in self._declarations.values():
            variable = declaration.variable
            if type(variable) not in (Real, Boolean):
                continue
            if variable.causality == Fmi2Causality.input:
                cached.append((declaration, 0))
            elif variable.causality == Fmi2Causality.output:
                computed = declaration.depends_on and variable.name not in self._outputs_of_the_state()
                cached.append((declaration, 2 if computed else 1))
        return cached

    def _outputs_of_the_state(self) -> frozenset[str]:
        """The outputs declared with ``depends_on`` whose getters, as the slave is set up now, read only the state and
        the time (the SensorChain's measurement behind its analog filter): the runtime serves them from the buffer,
        written when a step ends, as any output of the state. Asked at the end of initialisation. Default: none."""
        return frozenset()

    def _bind_value_cache(self, buffer: bytearray) -> None:
        """The runtime's buffer (``_value_cache_layout``'s slots, doubles), filled with the current values; the view
        kept of it pins it (a bytearray with a view cannot be resized)."""
        cached = list(enumerate(self._cached_declarations(), start=FIRST_SLOT))
        self._cache_inputs = [(slot, d.variable.name, _COERCE[type(d.variable)]) for slot, (d, role) in cached
                              if role == 0]
        self._cache_outputs = [(slot, d.variable.getter) for slot, (d, role) in cached if role == 1]
        self._cache_state = [(slot, d.variable.name, _COERCE[type(d.variable)]) for slot, (d, role) in cached
                             if role == 1 and not d.computed]
        self._cache_computed = [(slot, d.variable.getter) for slot, (d, role) in cached if role == 2]
        self._cache_slots = {d.variable.name: slot for slot, (d, _) in cached}
        self._computed_slots = {kind: {d.variable.value_reference: slot for slot, (d, role) in cached
                                       if role == 2 and type(d.variable) is kind} for kind in _COERCE}
        self._value_cache = memoryview(buffer).cast("d")
        try:
            self._write_cache()
        except Exception:  # the runtime then leaves the cache off: so does the slave
            self._value_cache = None
            raise

    def _value_cache_core(self) -> tuple[int, int, int, object] | None:
        """A compiled core for the runtime to step this slave on the buffer (:mod:`nfal.models.plant_core`):
        (its address, its data's address, the data's size in doubles, the data's owner), or None: none."""
        address = self._core_address()
        if address is None:
            return None
        self._core_data = self._packed_core()
        return address, self._core_data.ctypes.data, self._core_data.size, self._core_data

    def _core_address(self) -> int | None:
        """The address of the slave's compiled core as it is set up now (its core module's ``step_address()``), or
        None: none (the default). A slave with one gives its data too (:meth:`_packed_core`)."""
        return None

    def _packed_core(self):
        """The core's data for the slave as it is now: a float64 numpy array (its module's ``pack``)."""
        raise NotImplementedError

    def _sync_core(self) -> None:
        """After a step in Python and a restore: the runtime holds every step for the slave's Python while it is not
        initialised (a state restored from before initialisation ended); else its core gets the state."""
        self._value_cache[CORE_HELD] = 0.0 if self.initialized else 1.0
        if self.initialized:
            self._store_core_state()

    def _store_core_state(self) -> None:
        """The slave's state, as its Python stepped or restored it (initialised), into its compiled core's data: by
        default its data packed again, in place (the runtime holds its address)."""
        if self._core_data is not None:
            self._core_data[:] = self._packed_core()

    def _take_core_state(self) -> None:
        """What the compiled core stepped besides the outputs (the state it keeps in its data), into the slave's
        state. Default: nothing (the ReynoldsPlant's state is its outputs)."""

    def _cache_slot(self, name: str) -> int:
        """The buffer slot of the cached variable ``name``."""
        return self._cache_slots[name]

    def _take_from_cache(self) -> None:
        """The state the runtime's core stepped (outputs and time) and the inputs it was set, into the attributes."""
        cache = self._value_cache
        if cache[CORE_STEPPED]:
            cache[CORE_STEPPED] = 0.0
            for slot, name, coerce in self._cache_state:
                setattr(self, name, coerce(cache[slot]))
            self.time = cache[CORE_TIME]
            self._take_core_state()
        if cache[INPUTS_WAITING]:
            self._take_inputs()

    def _take_inputs(self) -> None:
        """The inputs the runtime was set, into their attributes (finite, as the setters check)."""
        cache = self._value_cache
        cache[INPUTS_WAITING] = 0.0
        for slot, name, coerce in self._cache_inputs:
            setattr(self, name, coerce(cache[slot]))
        self._settings_changed = True

    def _write_cache(self) -> None:
        """Every cached variable's current value into the buffer, what it holds for the slave taken first."""
        self._take_from_cache()
        self._write_inputs()
        self._write_state_outputs()
        self._write_computed()

    def _write_inputs(self) -> None:
        cache = self._value_cache
        for slot, name, _ in self._cache_inputs:
            cache[slot] = getattr(self, name)

    def _write_state_outputs(self) -> None:
        cache = self._value_cache
        for slot, getter in self._cache_outputs:
            cache[slot] = getter()

    def _write_computed(self) -> None:
        """The outputs computed from the inputs (taken first), into the buffer, which then has them up to date."""
        cache = self._value_cache
        self._take_from_cache()
        for slot, getter in self._cache_computed:
            cache[slot] = getter()
        cache[COMPUTED_STALE] = 0.0

    def set_real(self, vrs, values) -> None:
        self._set(Real, vrs, values, "setReal")

    def set_integer(self, vrs, values) -> None:
        self._set(Integer, vrs, values, "setInteger")

    def set_boolean(self, vrs, values) -> None:
        self._set(Boolean, vrs, values, "setBoolean")

    def set_string(self, vrs, values) -> None:
        self._set(String, vrs, values, "setString")

    def get_real(self, vrs):
        return self._get(Real, vrs, "getReal")

    def get_integer(self, vrs):
        return self._get(Integer, vrs, "getInteger")

    def get_boolean(self, vrs):
        return self._get(Boolean, vrs, "getBoolean")

    def get_string(self, vrs):
        return self._get(String, vrs, "getString")

    # --- FMU state ---------------------------------------------------------------------------------
    def _get_fmu_state(self) -> dict:
        if self._value_cache is not None:
            self._take_from_cache()

        def run():
            values = {name: getattr(self, name) for name, d in self._declarations.items() if not d.computed}
            return {"model": self.modelName, "time": self.time, "start_time": self.start_time,
                    "initialized": self.initialized, "variables": values,
                    "internal": copy.deepcopy(self.get_internal_state())}
        return self._guard("getFMUstate", run)

    def _set_fmu_state(self, state: dict) -> None:
        def run():
            if not isinstance(state, dict) or "invalid" in state:
                raise FmuStateError(state.get("invalid") if isinstance(state, dict) else "not an FMU state")
            if state.get("model") != self.modelName:
                raise FmuStateError(f"a state of {state.get('model')!r}, not of {self.modelName}")
            variables = {name: value for name, value in state["variables"].items() if name in self._declarations}
            for name, value in variables.items():
                setattr(self, name, value)
            self.time, self.start_time = float(state["time"]), float(state["start_time"])
            if state["initialized"] and not self.initialized:  # a fresh instance: build its models first
                self.setup()
                for name, value in variables.items():
                    setattr(self, name, value)
            self.initialized = bool(state["initialized"])
            self.set_internal_state(copy.deepcopy(state["internal"]))
        cache = self._value_cache
        if cache is not None:  # what waits for the slave first: the state replaces what it holds
            self._take_from_cache()
        try:
            self._guard("setFMUstate", run)
        finally:
            if cache is not None:  # what the restore left, as far as it reads (the error is the restore's)
                self._sync_core()
                with contextlib.suppress(Exception):
                    self._write_inputs()
                    self._write_state_outputs()
                cache[COMPUTED_STALE] = 1.0

    @staticmethod
    def _fmu_state_to_bytes(state: dict) -> bytes:
        # Called on the class: never raise (a value JSON cannot hold becomes its repr, refused on restore).
        return json.dumps(state, default=repr).encode("utf-8")

    @staticmethod
    def _fmu_state_from_bytes(state: bytes) -> dict:
        # Called on the class (no instance to log with): never raise; _set_fmu_state reports.
        try:
            data = json.loads(bytes(state).decode("utf-8"))
        except (ValueError, UnicodeDecodeError) as exc:
            return {"invalid": f"serialized FMU state is not valid: {exc}"}
        return data if isinstance(data, dict) else {"invalid": "serialized FMU state is not a JSON object"}

    # --- modelDescription.xml -----------------------------------------------------------------------
    def to_xml(self, model_options: dict | None = None) -> Element:
        """pythonfmu's model description plus units, output dependencies and initial unknowns."""
        options = {"canGetAndSetFMUstate": self.CAN_SAVE_STATE, "canSerializeFMUstate": self.CAN_SAVE_STATE}
        options.update(model_options or {})
        root = super().to_xml(options)
        used = sorted({d.unit for d in self._declarations.values() if d.unit is not None})
        if used:
            definitions = Element("UnitDefinitions")
            for unit in used:
                node = SubElement(definitions, "Unit", name=unit)
                SubElement(node, "BaseUnit", {k: str(v) for k, v in UNITS[unit].items()})
            position = list(root).index(root.find("CoSimulation")) + 1
            root.insert(position, definitions)
        by_name = {d.variable.name: d for d in self._declarations.values()}
        index = {}  # name -> 1-based index in ModelVariables
        for i, node in enumerate(root.find("ModelVariables").findall("ScalarVariable")):
            name = node.get("name")
            index[name] = i + 1
            declared = by_name.get(name)
            if declared is not None and declared.unit is not None:
                node.find("Real").set("unit", declared.unit)
        structure = root.find("ModelStructure")
        for child in list(structure):
            structure.remove(child)
        outputs = [d for d in by_name.values() if d.variable.causality == Fmi2Causality.output]
        if outputs:
            outputs.sort(key=lambda d: index[d.variable.name])
            node = SubElement(structure, "Outputs")
            for d in outputs:
                attributes = {"index": str(index[d.variable.name]),
                              "dependencies": " ".join(str(index[s]) for s in sorted(d.depends_on, key=index.get)),
                              "dependenciesKind": " ".join("dependent" for _ in d.depends_on)}
                SubElement(node, "Unknown", attributes)
            # every output is initial="calculated": an initial unknown that may depend on every known
            node = SubElement(structure, "InitialUnknowns")
            for d in outputs:
                SubElement(node, "Unknown", {"index": str(index[d.variable.name])})
        return root


def _kind_of(name: str, start) -> type:
    if isinstance(start, bool):
        return Boolean
    for python_type in (int, float, str):
        if isinstance(start, python_type):
            return _PY_TYPES[python_type]
    raise InvalidParameterError(name, start, "a float, int, bool or str start value")
