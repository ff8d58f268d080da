"""Run an SSP archive in OSP libcosim (the ``libcosimpy`` bindings): the third-party check of our structures.

:func:`run_ssp` loads an ``.ssp`` (or an SSP folder, or an ``.ssd``) exactly as libcosim does, drives
chosen inputs from Python every communication step through an override manipulator, and returns
the observed variables as numpy arrays. libcosim's fixed-step algorithm steps every FMU from t_k
to t_k + h with the inputs it holds, then copies outputs to the connected inputs: a Jacobi scheme,
so every feedthrough element adds one step of delay (``algorithm="jacobi"`` of our orchestrator
does the same).

What libcosim does differently from SSP 1.0, and how :func:`run_ssp` compensates (details in
``docs/cosimulation.md``, "Third-party hosts"):

* it applies only the **first** ``ssd:ParameterBinding`` of each component. With
  ``apply_all_bindings=True`` (default) every binding is applied again, in order, as initial
  values, so later bindings win as the standard says; names an FMU does not have are ignored,
  also as the standard says.
* it cannot load a connection from a system connector, so a driven input is left unconnected
  in the SSD and set here.

pythonfmu FMUs load in this process without ``LD_PRELOAD``: the Python executable has already
loaded ``libpython``, whose symbols the FMU binary needs. Non-Python hosts (``cosim`` CLI, a
C++ program) load nfal's FMUs as they are (their loader starts the Python they recorded,
docs/cosimulation.md, "The loader"); other pythonfmu FMUs need :func:`preload_environment`.

``libcosimpy`` is imported lazily; without it, :class:`LibcosimUnavailableError` says how to get it.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import sysconfig
import time as _time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from nfal.errors import (InvalidParameterError, LibcosimUnavailableError, SimulationError, StructureError,
                         UnknownConnectorError, UnknownElementError)

from .ssp import DefaultExperiment, System, parse_boolean, read_ssp

logger = logging.getLogger(__name__)

#: libcosim's log levels, quietest last.
LOG_LEVELS = ("trace", "debug", "info", "warning", "error", "fatal")
_NS_PER_S = 1_000_000_000

InputSignal = Callable[[float], float] | float | int | bool


@dataclasses.dataclass(frozen=True)
class LibcosimRun:
    """One libcosim run, SI units.

    Attributes
    ----------
    structure : str
        The archive (or folder, or .ssd) that ran.
    time_s : ndarray
        The communication points after each step, t_1 .. t_N [s] (libcosim gives no access to the
        values at t_0 before the first step).
    values : dict of str to ndarray
        ``"Element.variable"`` -> its value at each of ``time_s`` (Booleans as 0/1).
    inputs : dict of str to ndarray
        ``"Element.variable"`` -> the value driven over each step [t_k, t_k+1), k = 0 .. N-1.
    step_size_s : float
    wall_time_s : float
        Loading, initialising and stepping.
    """

    structure: str
    time_s: np.ndarray
    values: dict[str, np.ndarray]
    inputs: dict[str, np.ndarray]
    step_size_s: float
    wall_time_s: float

    def __getitem__(self, name: str) -> np.ndarray:
        if name in self.values:
            return self.values[name]
        if name in self.inputs:
            return self.inputs[name]
        raise KeyError(f"{name!r} was not observed; observed: {', '.join(sorted(self.values))}")


@dataclasses.dataclass(frozen=True)
class _Variable:
    slave: int
    reference: int
    type: int  # libcosim: 0 real, 1 integer, 2 string, 3 boolean
    causality: int  # 0 input, 1 parameter, 2 output, 3 calculated parameter, 4 local, 5 independent


_REAL, _INTEGER, _STRING, _BOOLEAN = 0, 1, 2, 3
_TYPE_NAMES = {_REAL: "Real", _INTEGER: "Integer", _STRING: "String", _BOOLEAN: "Boolean"}


# --- the host's libpython ---------------------------------------------------------------------------

def libpython_path() -> Path | None:
    """The shared libpython of this interpreter (``LIBDIR``/``INSTSONAME``, else ``LDLIBRARY``), or None if static."""
    libdir = sysconfig.get_config_var("LIBDIR")
    for key in ("INSTSONAME", "LDLIBRARY"):
        name = sysconfig.get_config_var(key)
        if libdir and name and (".so" in name or name.endswith(".dylib")):  # not libpythonX.Y.a
            candidate = Path(libdir) / name
            if candidate.is_file():
                return candidate
    return None


def preload_environment(environ: Mapping[str, str] | None = None) -> dict[str, str]:
    """A copy of ``environ`` (default ``os.environ``) with this interpreter's libpython first in ``LD_PRELOAD``.

    What a non-Python FMI host (libcosim's ``cosim`` CLI, a C++ program) needs to load stock pythonfmu
    FMUs: their binary uses libpython's symbols but does not link it (nfal's FMUs need nothing). Raises
    :class:`LibcosimUnavailableError` for a statically linked interpreter (no libpython to preload).
    """
    env = dict(os.environ if environ is None else environ)
    library = libpython_path()
    if library is None:
        raise LibcosimUnavailableError(
            "this Python is linked statically (no shared libpython): a non-Python host cannot load pythonfmu "
            "FMUs with it; use a Python built with --enable-shared")
    env["LD_PRELOAD"] = os.pathsep.join(p for p in (str(library), env.get("LD_PRELOAD", "")) if p)
    return env


# --- reading the structure ----------------------------------------------------------------------------

def _bindings(system: System) -> dict[str, list[tuple[str, list[tuple[str, object]]]]]:
    """Component -> its parameter bindings in SSD order: (origin, [(variable name, value), ...]), each
    binding's ``prefix`` prepended to its names (SSP 1.0), as the master reads them (:mod:`.ssp`)."""
    return {name: [(binding.origin, [(binding.prefix + value.name, value.value)
                                     for value in binding.parameter_set.values])
                   for binding in component.parameter_bindings]
            for name, component in system.components()}


# --- libcosimpy -------------------------------------------------------------------------------------

def _libcosimpy():
    try:  # on use: libcosimpy is optional (the test extra)
        from libcosimpy import CosimLogging
        from libcosimpy._internal import get_last_error_message
        from libcosimpy.CosimExecution import CosimExecution
        from libcosimpy.CosimManipulator import CosimManipulator
        from libcosimpy.CosimObserver import CosimObserver
    except ImportError as error:
        raise LibcosimUnavailableError(
            f"OSP libcosim's Python bindings are not installed ({error}): pip install libcosimpy "
            "(or pip install 'nfal[test]')") from None
    except OSError as error:  # the bundled libcosimc.so failed to load
        raise LibcosimUnavailableError("libcosimpy is installed but its libcosimc library cannot load: "
                                       f"{error}") from None
    return CosimExecution, CosimLogging, CosimManipulator, CosimObserver, get_last_error_message


def _convert(value: object, variable_type: int, name: str):
    try:
        if variable_type == _REAL:
            number = float(value)
            if not math.isfinite(number):
                raise ValueError
            return number
        if variable_type == _INTEGER:
            return int(value)
        if variable_type == _BOOLEAN:
            if isinstance(value, str):
                if parse_boolean(value) is None:
                    raise ValueError
                return parse_boolean(value)
            return bool(value)
        return str(value)
    except (TypeError, ValueError):
        raise InvalidParameterError(name, value, f"a finite {_TYPE_NAMES[variable_type]} value") from None


def run_ssp(archive: str | Path, stop_time: float | None = None, *, step_size: float | None = None,
            inputs: Mapping[str, InputSignal] | None = None, observe: Sequence[str] | None = None,
            parameters: Mapping[str, object] | None = None, apply_all_bindings: bool = True,
            log_level: str = "error", realtime: bool = False) -> LibcosimRun:
    """Run ``archive`` in OSP libcosim with a fixed step, driving ``inputs`` and recording ``observe``.

    Parameters
    ----------
    archive : path
        An ``.ssp`` archive (as packed by :func:`nfal.orchestration.ssp_archive.pack`), an SSP
        folder holding ``SystemStructure.ssd``, or an ``.ssd`` file.
    stop_time : float, optional
        [s]; default the SSD's ``DefaultExperiment stopTime``.
    step_size : float, optional
        Communication step [s]; default the SSD's OSP ``FixedStepAlgorithm baseStepSize``
        annotation (which libcosim reads itself).
    inputs : mapping, optional
        ``{"Element.variable": signal}``: a function of time [s] or a constant, evaluated at the
        start t_k of every step and applied (override manipulator) for that step. Real, Integer
        or Boolean variables; usually an unconnected input such as ``Controller.reference``.
    observe : sequence of str, optional
        ``"Element.variable"`` names to record after every step; default every output of every
        element. Real, Integer or Boolean.
    parameters : mapping, optional
        ``{"Element.variable": value}`` initial values applied after the SSD's bindings.
    apply_all_bindings : bool
        Apply every ``ParameterBinding`` of every component in order (SSP semantics), not only the
        first one libcosim applies (default True).
    log_level : str
        libcosim's console log level, one of :data:`LOG_LEVELS` (default ``"error"``; ``"warning"``
        shows, among others, every binding parameter an element does not have).
    realtime : bool
        Let libcosim pace the steps on the wall clock (its real-time mode, factor 1): for an FMU that
        talks to hardware, such as the HardwareProxy.

    Returns
    -------
    LibcosimRun

    Raises
    ------
    LibcosimUnavailableError
        libcosimpy is missing.
    StructureError, UnknownElementError, UnknownConnectorError
        libcosim cannot load the structure, or a name in ``inputs``/``observe``/``parameters``
        does not exist (the message lists what does).
    SimulationError
        A step failed; ``error.result`` holds the run up to the failure.
    """
    started = _time.perf_counter()
    path = Path(archive)
    if not path.exists():
        raise InvalidParameterError("archive", str(path), "an existing .ssp archive, SSP folder or .ssd file")
    if log_level not in LOG_LEVELS:
        raise InvalidParameterError("log_level", log_level, f"one of {', '.join(LOG_LEVELS)}")
    with read_ssp(path) as structure:
        start, step, steps = _experiment(structure.default_experiment, stop_time, step_size)
        bindings = _bindings(structure.system) if apply_all_bindings else {}
    CosimExecution, CosimLogging, CosimManipulator, CosimObserver, last_error = _libcosimpy()
    CosimLogging.log_output_level(CosimLogging.CosimLogLevel[log_level.upper()])
    try:
        execution = (CosimExecution.from_ssp_file(str(path)) if step_size is None
                     else CosimExecution.from_ssp_file(str(path), round(step * _NS_PER_S)))
    except AssertionError:
        raise StructureError(f"libcosim cannot load {path}: {last_error()}") from None
    variables = _Variables(execution)
    _apply_bindings(execution, variables, bindings)
    for name, value in (parameters or {}).items():
        variable = variables.lookup(name, "parameter")
        _set_initial(execution, variable, _convert(value, variable.type, name), name)
    driven = [(name, variables.lookup(name, "input", numeric=True),
               signal if callable(signal) else (lambda t, value=signal: value))
              for name, signal in (inputs or {}).items()]
    if observe is None:
        observe = [name for name, v in variables.items() if v.causality == 2 and v.type != _STRING]
    watched = [(name, variables.lookup(name, "observed variable", numeric=True)) for name in observe]
    if realtime and not execution.real_time_simulation_enabled(True):
        raise SimulationError(f"libcosim: cannot enable real-time simulation: {last_error()}")
    observer = CosimObserver.create_last_value()
    manipulator = CosimManipulator.create_override()
    execution.add_observer(observer)
    execution.add_manipulator(manipulator)
    recording = _Recording(path, start, step, steps, watched, driven, started)
    try:
        _step_all(execution, manipulator, _readers(observer, watched), recording, driven, last_error)
    except SimulationError as error:
        error.result = recording.result()
        raise
    finally:
        del execution
    run = recording.result()
    logger.info("libcosim ran %s: %d steps of %g s in %.2f s", path.name, steps, step, run.wall_time_s)
    return run


def _experiment(experiment: DefaultExperiment, stop_time: float | None,
                step_size: float | None) -> tuple[float, float, int]:
    """(start, step, number of steps): the arguments where given, else the SSD's DefaultExperiment."""
    start = experiment.start_time or 0.0
    stop = experiment.stop_time if stop_time is None else stop_time
    step = experiment.step_size if step_size is None else step_size
    if stop is None:
        raise InvalidParameterError("stop_time", None, "a time [s] (the SSD has no DefaultExperiment stopTime)")
    if step is None:
        raise InvalidParameterError("step_size", None, "a step [s] (the SSD has no OSP FixedStepAlgorithm annotation)")
    if not (math.isfinite(step) and step > 0):
        raise InvalidParameterError("step_size", step, "a finite step > 0 s")
    step_ns = round(step * _NS_PER_S)
    if step_ns <= 0 or abs(step_ns - step * _NS_PER_S) > 1e-6 * step * _NS_PER_S:
        raise InvalidParameterError("step_size", step, "a whole number of nanoseconds (libcosim's time resolution)")
    if not (math.isfinite(stop) and stop > start):
        raise InvalidParameterError("stop_time", stop, f"a time > the start time {start:g} s")
    steps = int(round((stop - start) / step))
    if steps < 1 or abs(steps * step - (stop - start)) > 1e-9 * max(1.0, stop):
        raise InvalidParameterError("stop_time", stop, f"start {start:g} s plus a whole number of {step:g} s steps")
    return start, step, steps


class _Variables(dict):
    """``"Element.variable"`` -> :class:`_Variable` of every variable libcosim loaded."""

    def __init__(self, execution) -> None:
        super().__init__()
        for info in execution.slave_infos():
            element = info.name.decode()
            for description in execution.slave_variables(info.index):
                self[f"{element}.{description.name.decode()}"] = _Variable(
                    info.index, description.reference, description.type, description.causality)
        self.elements = sorted({name.split(".", 1)[0] for name in self})

    def lookup(self, name: str, role: str, numeric: bool = False) -> _Variable:
        """The variable ``name`` (a ``role`` in messages); with ``numeric``, a String one is refused."""
        element, _, variable = name.partition(".")
        if element not in self.elements:
            raise UnknownElementError(f"{role} {name!r}: no element {element!r}; elements: {', '.join(self.elements)}")
        if name not in self:
            known = sorted(v.split(".", 1)[1] for v in self if v.startswith(element + "."))
            raise UnknownConnectorError(f"{role} {name!r}: {element} has no variable {variable!r}; it has "
                                        f"{', '.join(known)}")
        if numeric and self[name].type == _STRING:
            raise InvalidParameterError(f"{role} {name}", "String", "a Real, Integer or Boolean variable")
        return self[name]


def _apply_bindings(execution, variables: _Variables, bindings) -> None:
    """Every binding of every component again, in order, as initial values (libcosim applies only the first)."""
    for element, sets in bindings.items():
        for label, values in sets:
            for name, value in values:
                variable = variables.get(f"{element}.{name}")
                if variable is None or variable.causality not in (0, 1):
                    continue  # SSP: a name without a matching parameter is ignored
                _set_initial(execution, variable, _convert(value, variable.type, f"{label}: {name}"),
                             f"{element}.{name}")


class _Recording:
    """The observed and driven values, step by step; :meth:`result` is the run up to the last complete step."""

    def __init__(self, path: Path, start: float, step: float, steps: int, watched, driven, started: float) -> None:
        self.path, self.start, self.step, self.steps, self.started = path, start, step, steps, started
        self.values = {name: np.full(steps, np.nan) for name, _ in watched}
        self.driven = {name: np.full(steps, np.nan) for name, _, _ in driven}
        self.done = 0

    def result(self) -> LibcosimRun:
        done = self.done
        times = self.start + self.step * np.arange(1, self.steps + 1)
        return LibcosimRun(str(self.path), times[:done], {k: v[:done] for k, v in self.values.items()},
                           {k: v[:done] for k, v in self.driven.items()}, self.step,
                           _time.perf_counter() - self.started)


def _step_all(execution, manipulator, readers, recording: _Recording, driven, last_error) -> None:
    """Step to the end: each step's inputs at its start t_k (set only when they change), then its outputs."""
    setters = {_REAL: manipulator.slave_real_values, _INTEGER: manipulator.slave_integer_values,
               _BOOLEAN: manipulator.slave_boolean_values}
    last = {}
    for k in range(recording.steps):
        t = recording.start + k * recording.step
        for name, variable, signal in driven:
            value = _convert(np.asarray(signal(t)).item(), variable.type, f"input {name} at t = {t:g} s")
            recording.driven[name][k] = value
            if last.get(name) != value:
                setters[variable.type](variable.slave, [variable.reference], [value])
                last[name] = value
        if not execution.step(1):
            raise SimulationError(f"libcosim: {last_error()} (in step {k} from t = {t:.9g} s)")
        for read in readers:
            read(recording.values, k)
        recording.done = k + 1


def _set_initial(execution, variable: _Variable, value, name: str) -> None:
    setter = {_REAL: execution.real_initial_value, _INTEGER: execution.integer_initial_value,
              _BOOLEAN: execution.boolean_initial_value, _STRING: execution.string_initial_value}[variable.type]
    if not setter(variable.slave, variable.reference, value):
        raise StructureError(f"libcosim refused the initial value {value!r} for {name}")


def _readers(observer, watched) -> list[Callable[[dict, int], None]]:
    """One reader per (element, type): a single libcosim call fetches all its observed values."""
    groups: dict[tuple[int, int], list[tuple[str, int]]] = {}
    for name, variable in watched:
        groups.setdefault((variable.slave, variable.type), []).append((name, variable.reference))
    getters = {_REAL: observer.last_real_values, _INTEGER: observer.last_integer_values,
               _BOOLEAN: observer.last_boolean_values}
    readers = []
    for (slave, variable_type), members in groups.items():
        names = [name for name, _ in members]
        references = [reference for _, reference in members]
        get = getters[variable_type]

        def read(values, k, slave=slave, names=names, references=references, get=get):
            for name, value in zip(names, get(slave, references)):
                values[name][k] = value

        readers.append(read)
    return readers
