"""nfal/apps/fig7_names.py against the structures it names: every name there is a variable of the loop it is for."""

from __future__ import annotations

import dataclasses

import pytest

from nfal.apps import fig7_names
from nfal.orchestration import read_ssp, resolve


def variables(archive) -> set[str]:
    """Every ``Element.variable`` of the structure's FMUs."""
    with read_ssp(archive) as structure:
        system = resolve(structure)
    return {f"{element.name}.{variable.name}" for element in system.elements
            for variable in element.model_description.modelVariables}


def column_names(columns: fig7_names.LoopColumns) -> set[str]:
    names = {getattr(columns, field.name) for field in dataclasses.fields(columns)
             if field.name not in ("extra_panels", "hardware")}
    return names | {name for panel in columns.extra_panels for name in panel[0]}


CONTROLLER = {fig7_names.REFERENCE, fig7_names.EXCITATION_COMMAND, fig7_names.DRIVE_VOLTAGE,
              fig7_names.SATURATED_TIME, fig7_names.CONTROLLER_CALIBRATION}
RIG = {fig7_names.RIG_DRIVE_INPUT, fig7_names.RIG_TRUE_HEIGHT, *fig7_names.RIG_READINGS.values()}


@pytest.mark.parametrize("structure, expected", [
    ("fig7_slow", CONTROLLER | column_names(fig7_names.SIMULATED) | RIG),
    ("fig7_reynolds", CONTROLLER | column_names(fig7_names.SIMULATED) | RIG | {fig7_names.PLANT_SHAPE}),
    ("fig7_hil", CONTROLLER | column_names(fig7_names.HARDWARE)),
    ("rig_slow", RIG),
    ("rig_reynolds", RIG | {fig7_names.PLANT_SHAPE}),
])
def test_every_name_is_a_variable_of_its_structure(fig7_archives, structure, expected):
    assert expected - variables(fig7_archives[structure]) == set()


def test_a_misspelt_name_would_be_caught(fig7_archives):
    assert "Controller.referense" not in variables(fig7_archives["fig7_slow"])


def test_the_loop_is_found_in_a_sub_system_by_its_elements_names():
    """A structure from another tool may put the Plant and the SensorChain in a sub-system (Mechanics.Plant): the
    metrics failed on 'no column Plant.height' and the checks were skipped, the run "ok"."""
    located = fig7_names.SIMULATED.located(["Mechanics.Plant", "Mechanics.SensorChain", "Controller",
                                            "ResonanceTracker", "Other.Plant.Probe"])
    assert (located.height, located.measured, located.excitation, located.reference) == (
        "Mechanics.Plant.height", "Mechanics.SensorChain.measured_height", "ResonanceTracker.excitation_amplitude",
        "Controller.reference")
    twice = fig7_names.SIMULATED.located(["A.Plant", "B.Plant"])
    assert twice.height == "Plant.height"  # which one? neither: not checked, as a structure without a Plant
    hardware = fig7_names.HARDWARE.located(["Loop.proxy", "Loop.Controller"])
    assert hardware.hardware and hardware.measured == "Loop.proxy.measured_height"
    assert hardware.extra_panels[0][0] == ("Loop.Controller.drive_voltage", "Loop.proxy.applied_voltage")
