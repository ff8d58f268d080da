"""An FMU instance over fmpy's low-level FMU2Slave, variables by name and log messages captured, and FMUs built
once per session and extracted: shared by the FMU tests."""

from __future__ import annotations

import gc
from pathlib import Path

import fmpy
from fmpy import extract, read_model_description
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions,
                       fmi2CallbackLoggerTYPE)

from nfal.fmus import build

FMI_ERROR = 3  # what our patched runtime (fmus/runtime/) answers a Python exception with


class Instance:
    """One FMU instance over fmpy's low-level FMU2Slave: variables by name, log messages captured."""

    def __init__(self, fmu_path: Path, unzipped: str, name: str = "instance", logging_on: bool = True,
                 messages: list | None = None) -> None:
        description = read_model_description(str(fmu_path))
        self.variables = {v.name: v for v in description.modelVariables}
        self.messages: list[tuple[int, str]] = [] if messages is None else messages  # (status, message)

        def log(_env, _instance, status, _category, message):
            self.messages.append((int(status), message.decode("utf-8", "replace")))

        self._callbacks = fmi2CallbackFunctions()
        self._callbacks.logger = fmi2CallbackLoggerTYPE(log)
        self._callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
        self._callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
        self.fmu = FMU2Slave(guid=description.guid, unzipDirectory=unzipped,
                             modelIdentifier=description.coSimulation.modelIdentifier, instanceName=name)
        self.fmu.instantiate(callbacks=self._callbacks, loggingOn=logging_on)
        self.time = 0.0

    def set(self, **values) -> None:
        for name, value in values.items():
            variable = self.variables[name]
            setter = {"Real": self.fmu.setReal, "Integer": self.fmu.setInteger, "Boolean": self.fmu.setBoolean,
                      "String": self.fmu.setString}[variable.type]
            setter([variable.valueReference], [value])

    def get(self, *names):
        values = []
        for name in names:
            variable = self.variables[name]
            getter = {"Real": self.fmu.getReal, "Integer": self.fmu.getInteger, "Boolean": self.fmu.getBoolean,
                      "String": self.fmu.getString}[variable.type]
            values.append(getter([variable.valueReference])[0])
        return values[0] if len(values) == 1 else tuple(values)

    def initialize(self, start_time: float = 0.0, **values) -> None:
        self.fmu.setupExperiment(startTime=start_time)
        self.fmu.enterInitializationMode()
        self.set(**values)
        self.fmu.exitInitializationMode()
        self.time = start_time

    def step(self, step_size: float) -> None:
        self.fmu.doStep(self.time, step_size)
        self.time += step_size

    def errors(self) -> list[str]:
        return [message for status, message in self.messages if status >= 3]

    def free(self) -> None:
        self.fmu.terminate()
        self.fmu.freeInstance()


def build_and_extract(tmp_path_factory, *names: str) -> dict[str, tuple[Path, str]]:
    """Build ``names`` once into a temporary folder; {name: (fmu path, unzipped folder)}."""
    out = tmp_path_factory.mktemp("fmus")
    paths = build.build_fmus(out, names)
    return {name: (path, extract(str(path), str(out / f"{name}_unzipped"))) for name, path in paths.items()}


def runtime_slave(class_name: str, instance_name: str | None = None):
    """The live Python slave of class ``class_name`` (the FMU's own copy of the class) that our runtime made in this
    process and bound its value cache to (fmus/value_cache/); one of that ``instance_name``, if given."""
    gc.collect()  # instances freed before: their slaves are in reference cycles
    (slave,) = [o for o in gc.get_objects() if type(o).__name__ == class_name and
                getattr(o, "_value_cache", None) is not None and
                instance_name in (None, getattr(o, "instance_name", None))]
    return slave


def refuses_a_state_from_before_initialisation(instance: Instance, step_size: float, read: str | None = None,
                                               **values) -> bool:
    """Set ``values`` in initialisation mode (and read the output ``read`` there: the provisional set-up's state), save
    the FMU state, leave initialisation, step three times (a compiled core's steps), restore the saved state: whether
    the next doStep then fails saying the instance is not initialised, as the slave's Python says."""
    from fmpy.fmi1 import FMICallException

    instance.fmu.setupExperiment(startTime=0.0)
    instance.fmu.enterInitializationMode()
    instance.set(**values)
    if read is not None:
        instance.get(read)
    early = instance.fmu.getFMUstate()
    instance.fmu.exitInitializationMode()
    for _ in range(3):
        instance.step(step_size)
    instance.fmu.setFMUstate(early)
    try:
        instance.step(step_size)
    except FMICallException:
        return any("initialisation" in error for error in instance.errors())
    finally:
        instance.fmu.freeFMUstate(early)
    return False


def python_do_steps(class_name: str) -> list:
    """The calls our runtime makes from now on to the Python ``do_step`` of the live slave of ``class_name``
    (:func:`runtime_slave`): a step its compiled core takes makes none."""
    slave, calls = runtime_slave(class_name), []
    original = slave.do_step
    slave.do_step = lambda *args: (calls.append(args), original(*args))[1]
    return calls
