"""Build the FMI 2.0 Reference FMUs Stair and Feedthrough from the sources in this folder.

The sources are modelica/Reference-FMUs' (README.md, LICENSE.txt): ``common/`` is shared by both,
``<Model>/`` holds its ``model.c``, ``config.h`` and ``modelDescription.xml``. The FMI 2.0 headers are
the ones the patched pythonfmu runtime vendors (``fmus/runtime/src/fmi``).
"""

from __future__ import annotations

import shutil
import subprocess
import zipfile
from pathlib import Path

HERE = Path(__file__).parent
FMI2_HEADERS = HERE.parents[1] / "fmus" / "runtime" / "src" / "fmi"
MODELS = ("Stair", "Feedthrough")
#: The structures around them, copied beside the built FMUs (they name ``<Model>.fmu`` relatively).
STRUCTURES = ("stair_feedthrough.ssd", "feedthrough_chain.ssd")


def compiler() -> str | None:
    """The C compiler on PATH, or None."""
    return shutil.which("cc") or shutil.which("gcc")


def build_reference_fmu(model: str, out_dir: Path) -> Path:
    """Compile ``model`` as a binary FMU (unprefixed fmi2 functions) into ``out_dir``/``model``.fmu."""
    sources = [HERE / "common", HERE / model]
    library = out_dir / f"{model}.so"
    subprocess.run([compiler(), "-shared", "-fPIC", "-O2", "-DDISABLE_PREFIX",
                    *(f"-I{folder}" for folder in (*sources, FMI2_HEADERS)),
                    "-o", str(library), str(HERE / "common" / "all.c"), "-lm"],
                   check=True, capture_output=True, text=True)
    fmu = out_dir / f"{model}.fmu"
    with zipfile.ZipFile(fmu, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.write(HERE / model / "modelDescription.xml", "modelDescription.xml")
        archive.write(library, f"binaries/linux64/{model}.so")
        for folder in sources:
            for source in sorted(folder.glob("*.[ch]")):
                archive.write(source, f"sources/{source.name}")
    library.unlink()
    return fmu


def build_reference_fmus(out_dir: Path) -> Path:
    """Build every model of :data:`MODELS` into ``out_dir`` with the structures beside them; return ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    for model in MODELS:
        build_reference_fmu(model, out_dir)
    for structure in STRUCTURES:
        shutil.copy2(HERE / structure, out_dir / structure)
    return out_dir
