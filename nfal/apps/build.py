"""The product's build: every FMU of ``fmus/`` and the SSP archives of ``ssp/`` that wire them (Fig. 7)."""

from __future__ import annotations

import importlib.resources
import logging
from pathlib import Path

from nfal.fmus.build import build_fmus
from nfal.orchestration.ssp_archive import pack

logger = logging.getLogger(__name__)

#: The system structures shipped in ``ssp/``, the default first.
STRUCTURES = ("fig7_slow", "fig7_reynolds", "fig7_hil")
#: The rig structures `nfal rig-emulator` plays (the rig's hardware, without the controller).
RIG_STRUCTURES = ("rig_slow", "rig_reynolds")
DEFAULT_BUILD_DIR = Path("build")


def structure_sources() -> Path:
    """The folder of the shipped ``.ssd`` and ``.ssv`` files (installed as ``nfal.ssp``)."""
    return Path(str(importlib.resources.files("nfal.ssp")))


def build_all(out_dir: str | Path = DEFAULT_BUILD_DIR, structures=STRUCTURES + RIG_STRUCTURES, *,
              fmi_version: int = 2, windows_python: Path | None = None) -> dict[str, Path]:
    """Build the FMUs into ``out_dir`` (only those missing or older than their sources) and pack
    ``<structure>.ssp`` for each of ``structures``. Returns {structure name: archive path}.

    ``fmi_version=3``: the FMUs are FMI 3.0 co-simulation FMUs (pythonfmu3, :mod:`nfal.fmus.fmi3`), and the
    archives the same structures wired to them (``nfal build --fmi 3`` puts them in ``build/fmi3/``).
    ``windows_python``: the FMUs carry win64 binaries too, which start that Windows CPython."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    fmus = build_fmus(out, fmi_version=fmi_version, windows_python=windows_python)
    logger.info("FMUs in %s: %s", out, ", ".join(sorted(fmus)))
    sources = structure_sources()
    archives = {}
    inputs = [*fmus.values(), *sources.glob("*.ssv")]
    for name in structures:
        ssd, archive = sources / f"{name}.ssd", out / f"{name}.ssp"
        if _newer_than(archive, [ssd, *inputs]):  # a read-only build/ that is up to date still runs
            archives[name] = archive
            continue
        archives[name] = pack(ssd, out, archive)
        logger.info("packed %s", archives[name])
    return archives


def _newer_than(target: Path, sources: list[Path]) -> bool:
    if not target.is_file():
        return False
    built = target.stat().st_mtime
    return all(Path(source).stat().st_mtime < built for source in sources)
