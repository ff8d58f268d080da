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
C++ program) need :func:`preload_environment`.

``libcosimpy`` is imported lazily; without it, :class:`LibcosimUnavailableError` says how to get it.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import sysconfig
import time as _time
import zipfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path, PurePosixPath

import numpy as np
from lxml import etree

from nfal.errors import (InvalidParameterError, LibcosimUnavailableError, SimulationError,

                         StructureError, UnknownConnectorError, UnknownElementError)

from .ssp_schema import DEFAULT_SSD, SSD_NS, SSV_NS

logger = logging.getLogger(__name__)

#: libcosim's log levels, quietest last.
LOG_LEVELS = ("trace", "debug", "info", "warning", "error", "fatal")
OSP_NS = "http://opensimulationplatform.com/SSP/OSPAnnotations"
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

    What a non-Python FMI host (libcosim's ``cosim`` CLI, a C++ program) needs to load pythonfmu
    FMUs: their binary uses libpython's symbols but does not link it. Raises
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

class _Structure:
    """The SSD of an .ssp, an SSP folder or an .ssd, and the files it references (relative to the SSD)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        if path.suffix.lower() == ".ssp":
            if not zipfile.is_zipfile(path):
                raise StructureError(f"{path}: not an SSP archive (not a zip file)")
            with zipfile.ZipFile(path) as archive:
                self._members = {name: archive.read(name) for name in archive.namelist()
                                 if not name.lower().endswith(".fmu")}
            self._ssd_name, self._folder = DEFAULT_SSD, None
        elif path.is_dir():
            self._members, self._ssd_name, self._folder = None, DEFAULT_SSD, path
        elif path.suffix.lower() == ".ssd":
            self._members, self._ssd_name, self._folder = None, path.name, path.parent
        else:
            raise InvalidParameterError("archive", str(path), "an .ssp archive, an SSP folder or an .ssd file")
        self.root = self._xml(self._ssd_name)

    def read(self, relative: str) -> bytes:
        if self._members is not None:  # the SSD is at the archive's root
            name = str(PurePosixPath(relative))
            if name not in self._members:
                raise StructureError(f"{self.path}: {relative} is not in the archive")
            return self._members[name]
        file = self._folder / relative
        if not file.is_file():
            raise StructureError(f"{self.path}: {relative} does not exist ({file})")
        return file.read_bytes()

    def _xml(self, relative: str) -> etree._Element:
        parser = etree.XMLParser(resolve_entities=False, no_network=True)
        try:
            return etree.fromstring(self.read(relative), parser)
        except etree.XMLSyntaxError as error:
            raise StructureError(f"{self.path}: {relative} is not well-formed XML: {error}") from None

    def default_experiment(self) -> tuple[float, float | None, float | None]:
        """(startTime, stopTime, OSP baseStepSize) of the SSD's DefaultExperiment (None where absent)."""
        experiment = self.root.find(f"{{{SSD_NS}}}DefaultExperiment")
        if experiment is None:
            return 0.0, None, None
        start = float(experiment.get("startTime", 0.0))
        stop = experiment.get("stopTime")
        fixed = experiment.find(f".//{{{OSP_NS}}}FixedStepAlgorithm")
        step = None if fixed is None else float(fixed.get("baseStepSize"))
        return start, None if stop is None else float(stop), step

    def parameter_bindings(self) -> dict[str, list[tuple[str, list[tuple[str, str, str]]]]]:
        """Component -> its bindings in order: (label, [(name, ssv type, value text), ...])."""
        bindings = {}
        for component in self.root.iterfind(f"{{{SSD_NS}}}System/{{{SSD_NS}}}Elements/{{{SSD_NS}}}Component"):
            sets = []
            for binding in component.iterfind(f"{{{SSD_NS}}}ParameterBindings/{{{SSD_NS}}}ParameterBinding"):
                source = binding.get("source")
                if source:
                    label, parameter_set = source, self._xml(source)
                else:
                    label = "inline parameter values"
                    parameter_set = binding.find(f"{{{SSD_NS}}}ParameterValues/{{{SSV_NS}}}ParameterSet")
                    if parameter_set is None:
                        continue
                prefix = binding.get("prefix", "")
                values = []
                for parameter in parameter_set.iterfind(f"{{{SSV_NS}}}Parameters/{{{SSV_NS}}}Parameter"):
                    typed = next((c for c in parameter if isinstance(c.tag, str)), None)
                    name = parameter.get("name", "")
                    if typed is None or (prefix and not name.startswith(prefix)):
                        continue
                    values.append((name[len(prefix):], etree.QName(typed).localname, typed.get("value")))
                sets.append((label, values))
            bindings[component.get("name")] = sets
        return bindings


# --- libcosimpy -------------------------------------------------------------------------------------

def _libcosimpy():
    try:
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
        raise LibcosimUnavailableError(f"libcosimpy is installed but its libcosimc library cannot load: {error}") from None
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
                if value.strip().lower() not in ("true", "false", "1", "0"):
                    raise ValueError
                return value.strip().lower() in ("true", "1")
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
    structure = _Structure(path)
    start, default_stop, default_step = structure.default_experiment()
    stop = default_stop if stop_time is None else stop_time
    step = default_step if step_size is None else step_size
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

    CosimExecution, CosimLogging, CosimManipulator, CosimObserver, last_error = _libcosimpy()
    CosimLogging.log_output_level(CosimLogging.CosimLogLevel[log_level.upper()])
    try:
        execution = (CosimExecution.from_ssp_file(str(path)) if step_size is None
                     else CosimExecution.from_ssp_file(str(path), step_ns))
    except AssertionError:
        raise StructureError(f"libcosim cannot load {path}: {last_error()}") from None

    variables = _variables(execution)
    elements = sorted({name.split(".", 1)[0] for name in variables})

    def lookup(name: str, role: str) -> _Variable:
        element, _, variable = name.partition(".")
        if element not in elements:
            raise UnknownElementError(f"{role} {name!r}: no element {element!r}; elements: {', '.join(elements)}")
        if name not in variables:
            known = sorted(v.split(".", 1)[1] for v in variables if v.startswith(element + "."))
            raise UnknownConnectorError(f"{role} {name!r}: {element} has no variable {variable!r}; it has "
                                        f"{', '.join(known)}")
        return variables[name]

    if apply_all_bindings:
        for element, sets in structure.parameter_bindings().items():
            for label, values in sets:
                for name, _, text in values:
                    variable = variables.get(f"{element}.{name}")
                    if variable is None or variable.causality not in (0, 1):
                        continue  # SSP: a name without a matching parameter is ignored
                    _set_initial(execution, variable, _convert(text, variable.type, f"{label}: {name}"),
                                 f"{element}.{name}")
    for name, value in (parameters or {}).items():
        variable = lookup(name, "parameter")
        _set_initial(execution, variable, _convert(value, variable.type, name), name)

    driven = []
    for name, signal in (inputs or {}).items():
        variable = lookup(name, "input")
        if variable.type == _STRING:
            raise InvalidParameterError(f"input {name}", "String", "a Real, Integer or Boolean variable")
        driven.append((name, variable, signal if callable(signal) else (lambda t, value=signal: value)))
    if observe is None:
        observe = [name for name, v in variables.items() if v.causality == 2 and v.type != _STRING]
    watched = []
    for name in observe:
        variable = lookup(name, "observed variable")
        if variable.type == _STRING:
            raise InvalidParameterError(f"observed variable {name}", "String", "a Real, Integer or Boolean variable")
        watched.append((name, variable))

    if realtime and not execution.real_time_simulation_enabled(True):
        raise SimulationError(f"libcosim: cannot enable real-time simulation: {last_error()}")
    observer = CosimObserver.create_last_value()
    manipulator = CosimManipulator.create_override()
    execution.add_observer(observer)
    execution.add_manipulator(manipulator)
    readers = _readers(observer, watched)
    setters = {_REAL: manipulator.slave_real_values, _INTEGER: manipulator.slave_integer_values,
               _BOOLEAN: manipulator.slave_boolean_values}

    values = {name: np.full(steps, np.nan) for name, _ in watched}
    driven_values = {name: np.full(steps, np.nan) for name, _, _ in driven}
    times = start + step * np.arange(1, steps + 1)
    last = {}
    done = 0
    try:
        for k in range(steps):
            t = start + k * step
            for name, variable, signal in driven:
                value = _convert(np.asarray(signal(t)).item(), variable.type, f"input {name} at t = {t:g} s")
                driven_values[name][k] = value
                if last.get(name) != value:
                    setters[variable.type](variable.slave, [variable.reference], [value])
                    last[name] = value
            if not execution.step(1):
                raise SimulationError(f"libcosim: step {k} from t = {t:.9g} s failed: {last_error()}")
            for read in readers:
                read(values, k)
            done = k + 1
    except SimulationError as error:
        error.result = _result(path, times, values, driven_values, step, started, done)
        raise
    finally:
        del execution
    run = _result(path, times, values, driven_values, step, started, done)
    logger.info("libcosim ran %s: %d steps of %g s in %.2f s", path.name, steps, step, run.wall_time_s)
    return run


def _result(path, times, values, driven, step, started, done) -> LibcosimRun:
    return LibcosimRun(str(path), times[:done], {k: v[:done] for k, v in values.items()},
                       {k: v[:done] for k, v in driven.items()}, step, _time.perf_counter() - started)


def _variables(execution) -> dict[str, _Variable]:
    found = {}
    for info in execution.slave_infos():
        element = info.name.decode()
        for description in execution.slave_variables(info.index):
            found[f"{element}.{description.name.decode()}"] = _Variable(
                info.index, description.reference, description.type, description.causality)
    return found


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
