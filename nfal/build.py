"""The product's build: every FMU of ``fmus/`` and the SSP archives of ``ssp/`` that wire them (Fig. 7)."""

from __future__ import annotations

import importlib.resources
import logging
from pathlib import Path

logger = logging.getLogger(__name__)

#: The system structures shipped in ``ssp/``, the default first.
STRUCTURES = ("fig7_slow", "fig7_reynolds", "fig7_hil")
#: The rig structures `nfal rig-emulator` plays (the rig's hardware, without the controller).
RIG_STRUCTURES = ("rig_slow", "rig_reynolds")
DEFAULT_BUILD_DIR = Path("build")


def structure_sources() -> Path:
    """The folder of the shipped ``.ssd`` and ``.ssv`` files (installed as ``nfal.ssp``)."""
    return Path(str(importlib.resources.files("nfal.ssp")))


def build_all(out_dir: str | Path = DEFAULT_BUILD_DIR, structures=STRUCTURES + RIG_STRUCTURES) -> dict[str, Path]:
    """Build the FMUs into ``out_dir`` (only those missing or older than their sources) and pack
    ``<structure>.ssp`` for each of ``structures``. Returns {structure name: archive path}."""
    from nfal.fmus.build import build_fmus
    from nfal.orchestration.ssp_archive import pack

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    fmus = build_fmus(out)
    logger.info("FMUs in %s: %s", out, ", ".join(sorted(fmus)))
    sources = structure_sources()
    archives = {}
    for name in structures:
        archives[name] = pack(sources / f"{name}.ssd", out, out / f"{name}.ssp")
        logger.info("packed %s", archives[name])
    return archives
