"""The names of the Fig. 7 loop's elements and variables, the one place the code spells them.

The structures (``ssp/fig7_*.ssd``, ``ssp/rig_*.ssd``) are the loop's wiring; this module only names what the
applications read and drive in them, and ``tests/test_fig7_names.py`` holds every name here to those files.
It imports nothing heavy, so the command line can use it at start-up.
"""

from __future__ import annotations

import dataclasses

#: The element that stands for the rig in the hardware-in-the-loop structure (fig7_hil).
PROXY = "proxy"
#: The Controller's reference input (what ``--reference`` drives) and its outputs.
REFERENCE = "Controller.reference"
#: The element that feeds REFERENCE in the Fig. 7 structures (the experiment in the archive;
#: fmus/reference_generator.py), its FMU's model identifier and its output.
REFERENCE_GENERATOR = "ReferenceGenerator"
GENERATED_REFERENCE = f"{REFERENCE_GENERATOR}.reference"
EXCITATION_COMMAND = "Controller.excitation_command"
DRIVE_VOLTAGE = "Controller.drive_voltage"
SATURATED_TIME = "Controller.saturated_time"
CONTROLLER_CALIBRATION = "Controller.calibration"
PLANT_SHAPE = "Plant.shape"
#: The Controller as the paper runs it, as parameters: the continuous placement of eqs. (23)-(24) and none of the
#: law's additions (lift-off mode, transducer lead, reference zero; docs/controller.md, "Beyond the paper's law").
PAPERS_LAW = {"Controller.placement": "continuous", "Controller.lift_off_time": 0.0, "Controller.actuator_lag": 0.0,
              "Controller.reference_zero": 0.0}


@dataclasses.dataclass(frozen=True)
class LoopColumns:
    """Where a loop variant keeps the quantities the metrics and the plot need."""

    height: str       #: the height the metrics judge (the true one where known)
    measured: str
    excitation: str
    frequency: str
    resting: str      #: true while the object rests on the surface
    extra_panels: tuple = ()
    reference: str = REFERENCE  #: the reference's column: the driven input, or GENERATED_REFERENCE
    command: str = EXCITATION_COMMAND  #: the Controller's excitation command
    saturated: str = SATURATED_TIME    #: how long the Controller's drive has been saturated [s]
    hardware: bool = False             #: the loop meets a rig (through the proxy)

    def located(self, element_names) -> "LoopColumns":
        """These columns with each element found by its own name wherever it sits in ``element_names`` (the
        structure's hierarchical names: a sub-system's Plant is Mechanics.Plant); a name found twice or not at all is
        kept as it is."""
        paths: dict[str, list[str]] = {}
        for name in element_names:
            paths.setdefault(name.rpartition(".")[2], []).append(name)

        def place(column: str) -> str:
            element, _, variable = column.partition(".")
            found = paths.get(element, [])
            return f"{found[0]}.{variable}" if len(found) == 1 else column

        fields = ("height", "measured", "excitation", "frequency", "resting", "reference", "command", "saturated")
        return dataclasses.replace(
            self, **{field: place(getattr(self, field)) for field in fields},
            extra_panels=tuple((tuple(map(place, names)), *rest) for names, *rest in self.extra_panels))


SIMULATED = LoopColumns("Plant.height", "SensorChain.measured_height", "ResonanceTracker.excitation_amplitude",
                        "ResonanceTracker.drive_frequency", "Plant.resting")
HARDWARE = LoopColumns(f"{PROXY}.measured_height", f"{PROXY}.measured_height", EXCITATION_COMMAND,
                       f"{PROXY}.drive_frequency", f"{PROXY}.resting", hardware=True,
                       extra_panels=((((DRIVE_VOLTAGE, f"{PROXY}.applied_voltage"), 1.0, "drive [V]")),
                                     (((f"{PROXY}.measurement_age",), 1e3, "sample age [ms]"))))

#: The rig structures (the loop without the Controller): the input the emulator's drive voltage goes to, the
#: outputs a rig reports (nfal.apps.rig_model), the true height and the excitation amplitude.
RIG_DRIVE_INPUT = "ResonanceTracker.drive_voltage"
RIG_READINGS = {"height": SIMULATED.measured, "drive_frequency": SIMULATED.frequency,
                "locked": "ResonanceTracker.locked", "resting": SIMULATED.resting}
RIG_TRUE_HEIGHT = SIMULATED.height
RIG_EXCITATION = SIMULATED.excitation
