"""Pack an SSD, its FMUs and its parameter sets into an SSP 1.0 archive (``.ssp``).

Layout (SSP 1.0, sec. 8): the SSD at the root as ``SystemStructure.ssd``, byte for byte; every
FMU and ``.ssv`` it references as ``resources/<name>``. References are taken from the SSD itself:
each ``ssd:Component source="resources/X.fmu"`` and each ``ssd:ParameterBinding
source="resources/Y.ssv"``. The archive is reproducible: members in sorted order with a fixed
timestamp, FMUs stored (they are zips already), XML deflated.
"""

from __future__ import annotations

import logging
import os
import zipfile
from collections.abc import Iterable
from pathlib import Path, PurePosixPath

from lxml import etree

from nfal.errors import InvalidParameterError, MissingFmuError, StructureError

from .ssp_schema import DEFAULT_SSD, SSD_NS, validate

logger = logging.getLogger(__name__)

RESOURCES = "resources"
_FIXED_TIME = (1980, 1, 1, 0, 0, 0)


def referenced_resources(ssd_path: str | Path) -> dict[str, list[str]]:
    """The archive members an SSD references: ``{"fmu": [...], "ssv": [...], "other": [...]}``.

    Each entry is the ``source`` as written (``resources/X.fmu``), in document order, without
    duplicates. Inline parameter values and same-document references are skipped.
    """
    path = Path(ssd_path)
    parser = etree.XMLParser(resolve_entities=False, no_network=True)
    try:
        root = etree.parse(str(path), parser).getroot()
    except (OSError, etree.XMLSyntaxError) as error:
        raise StructureError(f"{path}: cannot be read as an SSD: {error}") from None
    if root.tag != f"{{{SSD_NS}}}SystemStructureDescription":
        raise StructureError(f"{path}: root element is {root.tag}, not ssd:SystemStructureDescription")
    found: dict[str, list[str]] = {"fmu": [], "ssv": [], "other": []}
    for element in root.iter(f"{{{SSD_NS}}}Component", f"{{{SSD_NS}}}ParameterBinding"):
        source = element.get("source")
        if not source or source.startswith("#"):
            continue
        kind = PurePosixPath(source).suffix.lower().lstrip(".")
        bucket = found[kind if kind in ("fmu", "ssv") else "other"]
        if source not in bucket:
            bucket.append(source)
    return found


def _resource_name(source: str, ssd_path: Path) -> str:
    """``resources/X.fmu`` -> ``X.fmu``; anything else is an error (it could not be packed portably)."""
    member = PurePosixPath(source)
    if "://" in source or member.is_absolute() or len(member.parts) != 2 or member.parts[0] != RESOURCES:
        raise StructureError(f"{ssd_path.name}: source {source!r} is not a relative '{RESOURCES}/<file>' reference "
                             "(the SSP 1.0 archive layout this packer writes)")
    return member.name


def pack(ssd_path: str | Path, fmu_dir: str | Path, out_path: str | Path,
         ssv_paths: Iterable[str | Path] | None = None, *, check: bool = True) -> Path:
    """Pack ``ssd_path`` with its FMUs and parameter sets into the SSP archive ``out_path``.

    Parameters
    ----------
    ssd_path : path
        The system structure (written with ``resources/...`` sources).
    fmu_dir : path
        Folder holding every FMU the SSD references, by file name.
    out_path : path
        The ``.ssp`` to write (replaced atomically if it exists).
    ssv_paths : iterable of path, optional
        Parameter sets to use for the SSD's ``resources/<name>.ssv`` references, matched by file
        name; a referenced set not given here is taken from beside the SSD. Sets given but not
        referenced are packed too (as spare variants under ``resources/``).
    check : bool
        Validate the archive against the SSP 1.0 schemas after packing (default True); a problem
        raises :class:`~nfal.errors.StructureError` and leaves no archive behind.

    Returns
    -------
    Path
        ``out_path``.

    Raises
    ------
    MissingFmuError
        An FMU the SSD references is not in ``fmu_dir`` (the message lists what is there).
    StructureError
        A parameter set the SSD references cannot be found, a source is not ``resources/<file>``,
        or (``check``) the packed archive is not valid SSP 1.0.
    InvalidParameterError
        ``out_path`` does not end in ``.ssp``, ``fmu_dir`` is not a folder, an ``ssv_paths`` entry
        is not a file.
    """
    ssd_path, fmu_dir, out_path = Path(ssd_path), Path(fmu_dir), Path(out_path)
    if out_path.suffix.lower() != ".ssp":
        raise InvalidParameterError("out_path", str(out_path), "a file name ending in .ssp")
    if not fmu_dir.is_dir():
        raise InvalidParameterError("fmu_dir", str(fmu_dir), "an existing folder holding the FMUs")
    members = _members(ssd_path, fmu_dir, ssv_paths)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    partial = out_path.with_name(f".{out_path.stem}.partial.ssp")
    try:
        with zipfile.ZipFile(partial, "w") as archive:
            _write(archive, DEFAULT_SSD, ssd_path.read_bytes(), zipfile.ZIP_DEFLATED)
            for member in sorted(members):
                method = zipfile.ZIP_STORED if member.endswith(".fmu") else zipfile.ZIP_DEFLATED
                _write(archive, member, members[member].read_bytes(), method)
        if check:
            problems = validate(partial)
            if problems:
                raise StructureError(f"{out_path.name} is not a valid SSP 1.0 archive:\n" + "\n".join(problems))
        os.replace(partial, out_path)
    finally:
        partial.unlink(missing_ok=True)
    logger.info("packed %s: %s", out_path, ", ".join(sorted(members)))
    return out_path


def _members(ssd_path: Path, fmu_dir: Path, ssv_paths: Iterable[str | Path] | None) -> dict[str, Path]:
    """The archive's members besides the SSD: ``resources/<name>`` -> the FMU or parameter set to pack."""
    sources = referenced_resources(ssd_path)
    if sources["other"]:
        raise StructureError(f"{ssd_path.name}: source {sources['other'][0]!r} is neither an .fmu nor an .ssv")

    given = {}
    for ssv in ssv_paths or ():
        ssv = Path(ssv)
        if not ssv.is_file():
            raise InvalidParameterError("ssv_paths", str(ssv), "existing .ssv files")
        given[ssv.name] = ssv

    members: dict[str, Path] = {}
    missing_fmus = []
    for source in sources["fmu"]:
        name = _resource_name(source, ssd_path)
        fmu = fmu_dir / name
        if fmu.is_file():
            members[f"{RESOURCES}/{name}"] = fmu
        else:
            missing_fmus.append(name)
    if missing_fmus:
        present = sorted(p.name for p in fmu_dir.glob("*.fmu"))
        raise MissingFmuError(
            f"{ssd_path.name} references {', '.join(missing_fmus)}, not in {fmu_dir} "
            f"(it holds {', '.join(present) or 'no FMUs'}); build them first (nfal build)")
    for source in sources["ssv"]:
        name = _resource_name(source, ssd_path)
        ssv = given.get(name, ssd_path.parent / name)
        if not ssv.is_file():
            raise StructureError(f"{ssd_path.name} references the parameter set {name}: not among ssv_paths "
                                 f"({', '.join(sorted(given)) or 'none given'}) nor beside the SSD ({ssv})")
        members[f"{RESOURCES}/{name}"] = ssv
    for name, ssv in given.items():
        members.setdefault(f"{RESOURCES}/{name}", ssv)
    return members


def _write(archive: zipfile.ZipFile, name: str, data: bytes, method: int) -> None:
    info = zipfile.ZipInfo(name, date_time=_FIXED_TIME)
    info.compress_type = method
    info.external_attr = 0o644 << 16
    archive.writestr(info, data)
