"""Run an SSP archive in ecos (ecospy's C++ host library) and save Real variables at every communication point.

    python ecos_ssp_outputs.py SSP STOP_S STEP_S OUT.npz ELEMENT::VARIABLE...

The values are read through ecospy's API (``get_real``, full double precision), unlike the ``ecos`` command
line's CSV (6 decimals). Run in a subprocess by tests/test_experiment_archive.py, so that the host process's exit
cannot take the test run with it; OUT.npz (``time`` and one array per variable) is written before the exit.
"""

import sys

import numpy as np
from ecospy import EcosSimulation


def main(ssp: str, stop: str, step: str, out: str, *names: str) -> None:
    step_s = float(step)
    with EcosSimulation(step_size=step_s, ssp_path=ssp) as simulation:
        simulation.init()
        rows = []
        for k in range(round(float(stop) / step_s) + 1):
            if k:
                simulation.step()
            rows.append([simulation.get_time(), *(simulation.get_real(name) for name in names)])
    np.savez(out, time=np.array([row[0] for row in rows]),
             **{name: np.array([row[i + 1] for row in rows]) for i, name in enumerate(names)})


if __name__ == "__main__":
    main(*sys.argv[1:])
