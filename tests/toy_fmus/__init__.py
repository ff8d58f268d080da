"""Toy pythonfmu slaves for the orchestrator's tests, and :func:`build_toys` to build them once.

* ``Integrator`` (integrator.py): x' = u, exact for a held input, no direct feedthrough; parameters of
  every FMI type (x0, fail_time, frozen, decimation, label) and an Integer output (steps).
* ``Gain`` (gain.py): y = k u with direct feedthrough, declared in ModelStructure; u and y have no
  unit (so gains chain with anything), k is in 1/s.

pythonfmu 0.7 declares neither units nor output dependencies; each toy adds them in ``to_xml`` with
``_toy_xml.declare_units_and_dependencies`` (packed into the FMU as a project file).
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).parent
TOYS = {"Integrator": "integrator.py", "Gain": "gain.py"}


def build_toys(dest: Path) -> dict[str, Path]:
    """Build every toy FMU into ``dest`` (skipping those already there); return name -> .fmu path."""
    from pythonfmu.builder import FmuBuilder

    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    built = {}
    sys.path.insert(0, str(HERE))  # the build imports the script, which imports _toy_xml
    try:
        for name, script in TOYS.items():
            fmu = dest / f"{name}.fmu"
            if not fmu.exists():
                FmuBuilder.build_FMU(HERE / script, dest=dest, project_files=[HERE / "_toy_xml.py"])
            built[name] = fmu
    finally:
        sys.path.remove(str(HERE))
    return built


def without_dependencies(fmu: Path, dest: Path) -> Path:
    """A copy of ``fmu`` whose modelDescription.xml declares no output dependencies (as pythonfmu writes it)."""
    import re
    import zipfile

    with zipfile.ZipFile(fmu) as source, zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED) as target:
        for item in source.infolist():
            data = source.read(item)
            if item.filename == "modelDescription.xml":
                data = re.sub(rb' dependencies(Kind)?="[^"]*"', b"", data)
            target.writestr(item, data)
    return dest
