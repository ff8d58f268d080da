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


SIMULATED = LoopColumns("Plant.height", "SensorChain.measured_height", "ResonanceTracker.excitation_amplitude",
                        "ResonanceTracker.drive_frequency", "Plant.resting")
HARDWARE = LoopColumns(f"{PROXY}.measured_height", f"{PROXY}.measured_height", EXCITATION_COMMAND,
                       f"{PROXY}.drive_frequency", f"{PROXY}.resting",
                       extra_panels=((((DRIVE_VOLTAGE, f"{PROXY}.applied_voltage"), 1.0, "drive [V]")),
                                     (((f"{PROXY}.measurement_age",), 1e3, "sample age [ms]"))))

#: The rig structures (the loop without the Controller): the input the emulator's drive voltage goes to, the
#: outputs a rig reports (nfal.apps.rig_model), the true height and the excitation amplitude.
RIG_DRIVE_INPUT = "ResonanceTracker.drive_voltage"
RIG_READINGS = {"height": SIMULATED.measured, "drive_frequency": SIMULATED.frequency,
                "locked": "ResonanceTracker.locked", "resting": SIMULATED.resting}
RIG_TRUE_HEIGHT = SIMULATED.height
RIG_EXCITATION = SIMULATED.excitation
