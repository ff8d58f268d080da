"""Run one FMU alone in ecos (ecospy's C++ host library) and save its outputs at every step.

    python ecos_outputs.py FMU START_VALUES_JSON STOP_S STEP_S OUT.npz

Run in a subprocess by tests/test_fmi3.py, so that the host process's exit (where pythonfmu FMUs may
still crash: issue 15, item 1) cannot take the test run with it; OUT.npz is written before the exit.
"""

import json
import sys

import numpy as np
from ecospy import EcosSimulation, EcosSimulationStructure
from fmpy import read_model_description

GETTERS = {"Real": "get_real", "Float64": "get_real", "Integer": "get_integer", "Int32": "get_integer",
           "Boolean": "get_bool"}


def main(fmu: str, start_values: str, stop: str, step: str, out: str) -> None:
    outputs = [(v.name, GETTERS[v.type]) for v in read_model_description(fmu).modelVariables
               if v.causality == "output" and v.type in GETTERS]
    step_s = float(step)
    with EcosSimulationStructure() as structure:
        structure.add_model("m", fmu)
        structure.add_parameter_set("start", {f"m::{k}": v for k, v in json.loads(start_values).items()})
        with EcosSimulation(structure=structure, step_size=step_s) as simulation:
            simulation.init(parameter_set="start")
            rows = []
            for k in range(round(float(stop) / step_s) + 1):
                if k:
                    simulation.step()
                rows.append([getattr(simulation, getter)(f"m::{name}") for name, getter in outputs])
    np.savez(out, **{name: np.array(column) for (name, _), column in zip(outputs, zip(*rows))})


if __name__ == "__main__":
    main(*sys.argv[1:])
