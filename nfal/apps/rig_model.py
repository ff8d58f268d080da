"""The emulated rig's hardware: a rig structure stepped one sample period at a time.

The rig is played by the simulation's own blocks, wired by a rig structure (``ssp/rig_slow.ssd``,
``ssp/rig_reynolds.ssd``, or a user's): ResonanceTracker -> Plant -> SensorChain, with the tracker's
``drive_voltage`` input left for the emulator to drive. So "the truth" the emulator plays is a structure
that ``nfal run`` can simulate too, parameter for parameter. Two ways to run it, one interface
(``apply``, ``reading``, ``advance``, ``time``, ``true_height``, ``excitation_amplitude``, ``close``):

* :class:`InProcessRig`: the nfal FMUs' own slave classes as Python objects, wired as the structure says
  (no FMI calls: 77 against 110 us a tick for rig_slow, ``python bench/bench_rig_truth.py``; a 2 kHz emulator
  beside a 2 kHz host needs the margin);
* :class:`StructureRig`: the structure's FMUs through the co-simulation master (any FMUs, a user's too).

:func:`open_rig` takes the first when every element is an nfal FMU, else the second.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Mapping

from nfal.errors import InvalidParameterError, require_positive
from nfal.apps.fig7_names import RIG_DRIVE_INPUT, RIG_EXCITATION, RIG_READINGS, RIG_TRUE_HEIGHT
from nfal.fmus.resonance_tracker import ResonanceTracker
from nfal.fmus.reynolds_plant import ReynoldsPlant
from nfal.fmus.sensor_chain import SensorChain
from nfal.fmus.slow_plant import SlowPlant
from nfal.hil.firmware import RigReading
from nfal.orchestration import Master, read_ssp, resolve


class StructureRig:
    """Run the rig structure at ``path`` through the master, with the fixed step ``period_s``.

    Parameters
    ----------
    path : path-like
        An SSP archive, folder or .ssd of a rig structure (see :data:`RIG_READINGS` for the names it needs).
    period_s : float
        The sample period [s] (the step).
    parameters : mapping, optional
        ``"Element.variable" -> value`` overrides, as for ``nfal run --param``.
    """

    def __init__(self, path: str | os.PathLike, period_s: float,
                 parameters: Mapping[str, object] | None = None) -> None:
        self.voltage, self._name = 0.0, str(path)
        self._stack = contextlib.ExitStack()
        try:
            structure = self._stack.enter_context(read_ssp(path))
            system = resolve(structure, parameters)
            self.master = self._stack.enter_context(
                Master(system, step_size=period_s, inputs={RIG_DRIVE_INPUT: lambda t: self.voltage}))
            if self.master.overridden:  # the drive came from inside: a closed loop (fig7_slow), not a rig
                drivers = ", ".join(f"{link.source.element}.{link.source.name}" for link in self.master.overridden)
                raise InvalidParameterError("rig structure", str(path), f"one whose {RIG_DRIVE_INPUT} nothing inside "
                                            f"drives (the emulator does; here {drivers} does: a closed loop, not a "
                                            "rig; e.g. rig_slow)")
            columns = {column.name: index for index, column in enumerate(self.master.columns)}
            missing = [name for name in (*RIG_READINGS.values(), RIG_TRUE_HEIGHT) if name not in columns]
            if missing:
                raise InvalidParameterError("rig structure", str(path), f"one with the outputs {', '.join(missing)}")
            self._index = {key: columns[name] for key, name in RIG_READINGS.items()}
            self._true_height = columns[RIG_TRUE_HEIGHT]
            self._excitation = columns.get(RIG_EXCITATION)  # a user's structure may not name it
            self.master.instantiate()
            self.master.initialize(0.0)
        except BaseException:
            self._stack.close()
            raise

    def reading(self) -> RigReading:
        """What the rig's sensors say now."""
        row, index = self.master.row, self._index
        return RigReading(float(row[index["height"]]), float(row[index["drive_frequency"]]),
                          bool(row[index["locked"]]), bool(row[index["resting"]]))

    @property
    def true_height(self) -> float:
        """The object's true clearance now [m] (no sensor)."""
        return float(self.master.row[self._true_height])

    @property
    def excitation_amplitude(self) -> float:
        """The transducer's excitation amplitude ||a|| now [m], the plant's input."""
        if self._excitation is None:
            raise InvalidParameterError("rig structure", self._name, f"one with the output {RIG_EXCITATION}")
        return float(self.master.row[self._excitation])

    @property
    def time(self) -> float:
        return self.master.time

    def apply(self, voltage: float) -> None:
        """Drive ``voltage`` [V] from now on (the exchange at the current time is redone with it)."""
        if voltage != self.voltage:
            self.voltage = float(voltage)
            self.master.refresh()

    def advance(self) -> None:
        """One sample period with the voltage held."""
        self.master.step()

    def close(self) -> None:
        self._stack.close()

    def __enter__(self) -> "StructureRig":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


#: The links of the built-in rig structures: (source element, output, target element, input).
RIG_LINKS = frozenset({("ResonanceTracker", "excitation_amplitude", "Plant", "excitation_amplitude"),
                       ("ResonanceTracker", "drive_frequency", "Plant", "drive_frequency"),
                       ("Plant", "height", "SensorChain", "true_height")})


#: The nfal slave classes an :class:`InProcessRig` runs, by model identifier.
SLAVE_CLASSES = {cls.__name__: cls for cls in (SlowPlant, ReynoldsPlant, ResonanceTracker, SensorChain)}


def _resolved(path, parameters):
    with read_ssp(path) as structure:
        return resolve(structure, parameters)


def in_process_capable(system) -> bool:
    """Whether every element is an nfal FMU :class:`InProcessRig` can run, wired as :data:`RIG_LINKS`."""
    links = {(link.source.element, link.source.name, link.target.element, link.target.name) for link in system.links}
    plain = all(link.transformation is None for link in system.links)  # InProcessRig wires without transformations
    return links == RIG_LINKS and plain and all(e.model_description.coSimulation.modelIdentifier in SLAVE_CLASSES
                                                for e in system.elements)


class InProcessRig:
    """The rig structure's nfal FMUs as Python objects (see the module docstring); same parameters.

    The exchange at each communication point follows the causal order of :data:`RIG_LINKS`: the tracker's
    outputs (for the voltage in force) go to the plant, the plant's height to the sensor; ``advance``
    steps the three.
    """

    def __init__(self, system, period_s: float) -> None:
        if not in_process_capable(system):
            raise InvalidParameterError("rig structure", system.name,
                                        "ResonanceTracker -> Plant -> SensorChain of nfal FMUs")
        self.period_s = require_positive("period_s", period_s)
        self.voltage = 0.0
        self.time = 0.0
        slaves = {}
        for element in system.elements:
            slave = SLAVE_CLASSES[element.model_description.coSimulation.modelIdentifier](instance_name=element.name)
            for name, value in element.start_values.items():
                slave.set_value(name, value)
            slave.setup_experiment(0.0)
            slave.enter_initialization_mode()
            slaves[element.name] = slave
        self.tracker, self.plant, self.sensor = slaves["ResonanceTracker"], slaves["Plant"], slaves["SensorChain"]
        self.tracker.set_value("drive_voltage", 0.0)
        for slave in (self.tracker, self.plant, self.sensor):  # causal order: each sets up with its inputs set
            slave.exit_initialization_mode()
            self._exchange()

    def _exchange(self) -> None:
        tracker, plant = self.tracker, self.plant
        plant.set_value("excitation_amplitude", tracker.value("excitation_amplitude"))
        plant.set_value("drive_frequency", tracker.value("drive_frequency"))
        self.sensor.set_value("true_height", plant.value("height"))

    def apply(self, voltage: float) -> None:
        if voltage != self.voltage:
            self.voltage = float(voltage)
            self.tracker.set_value("drive_voltage", self.voltage)
            self._exchange()

    def reading(self) -> RigReading:
        tracker = self.tracker
        return RigReading(float(self.sensor.value("measured_height")), float(tracker.value("drive_frequency")),
                          bool(tracker.value("locked")), bool(self.plant.value("resting")))

    @property
    def true_height(self) -> float:
        return float(self.plant.value("height"))

    @property
    def excitation_amplitude(self) -> float:
        return float(self.tracker.value("excitation_amplitude"))

    def advance(self) -> None:
        t, dt = self.time, self.period_s
        for slave in (self.tracker, self.plant, self.sensor):
            slave.do_step(t, dt)
        self.time = t + dt
        self._exchange()

    def close(self) -> None:
        for slave in (self.tracker, self.plant, self.sensor):
            slave.terminate()

    def __enter__(self) -> "InProcessRig":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_rig(path, period_s: float, parameters: Mapping[str, object] | None = None):
    """The rig structure at ``path`` as an :class:`InProcessRig` if it can be, else a :class:`StructureRig`."""
    system = _resolved(path, parameters)
    if in_process_capable(system):
        return InProcessRig(system, period_s)
    return StructureRig(path, period_s, parameters)
