"""Validate SSP 1.0 files (.ssd, .ssv, .ssm, .ssb) and packed .ssp archives against the SSP schemas.

The normative XML Schema 1.0 files of SSP 1.0 are vendored in ``ssp/schema/`` (installed as
``nfal.ssp``; see its README for origin and license). All five namespaces are loaded into one
schema set, so the ``lax`` wildcards of the SSD (inline ``ssd:ParameterValues``, annotations)
validate any content of a known SSP namespace too; vendor annotations (``osp:`` ...) are skipped,
as the standard intends.

:func:`validate` checks what the standard says. :func:`libcosim_portability` additionally lists
what OSP libcosim (as of libcosimpy 0.0.6) would not load or would load differently; see
``docs/cosimulation.md``, "Third-party hosts".

Every problem is one string ``"<file>:<line>: <message>"``; members of an archive are named
``<archive>!<member>``. An empty list means valid.
"""

from __future__ import annotations

import functools
import importlib.resources
import logging
import zipfile
from pathlib import Path, PurePosixPath

from lxml import etree

from .ssp import DEFAULT_SSD, SSB_NS, SSC_NS, SSD_NS, SSM_NS, SSV_NS  # noqa: F401 - the SSP 1.0 names, re-exported

logger = logging.getLogger(__name__)

#: Namespace -> (vendored schema file, the prefix libcosim matches literally).
SCHEMAS = {
    SSD_NS: ("SystemStructureDescription.xsd", "ssd"),
    SSC_NS: ("SystemStructureCommon.xsd", "ssc"),
    SSV_NS: ("SystemStructureParameterValues.xsd", "ssv"),
    SSM_NS: ("SystemStructureParameterMapping.xsd", "ssm"),
    SSB_NS: ("SystemStructureSignalDictionary.xsd", "ssb"),
}

#: File extension -> the root element it must hold.
ROOTS = {
    ".ssd": f"{{{SSD_NS}}}SystemStructureDescription",
    ".ssv": f"{{{SSV_NS}}}ParameterSet",
    ".ssm": f"{{{SSM_NS}}}ParameterMapping",
    ".ssb": f"{{{SSB_NS}}}SignalDictionary",
}

#: The SSD an SSP archive must hold at its root (SSP 1.0, sec. 8).


def schema_dir() -> Path:
    """The folder of the vendored SSP 1.0 XSDs (``nfal.ssp/schema``)."""
    return Path(str(importlib.resources.files("nfal.ssp"))) / "schema"


@functools.lru_cache(maxsize=1)
def _schema() -> etree.XMLSchema:
    folder = schema_dir()
    imports = "".join(
        f'<xs:import namespace="{namespace}" schemaLocation="{(folder / name).as_uri()}"/>'
        for namespace, (name, _) in SCHEMAS.items()
    )
    driver = f'<xs:schema xmlns:xs="http://www.w3.org/2001/XMLSchema">{imports}</xs:schema>'
    parser = etree.XMLParser(resolve_entities=False, no_network=True)
    return etree.XMLSchema(etree.fromstring(driver.encode(), parser, base_url=folder.as_uri() + "/"))


def _parse(data: bytes, label: str) -> tuple[etree._ElementTree | None, list[str]]:
    parser = etree.XMLParser(resolve_entities=False, no_network=True, remove_blank_text=False)
    try:
        return etree.ElementTree(etree.fromstring(data, parser)), []
    except etree.XMLSyntaxError as error:
        entries = [(e.line, e.message) for e in parser.error_log if e.level >= etree.ErrorLevels.ERROR]
        return None, [f"{label}:{line}: not well-formed XML: {message}"
                      for line, message in entries or [(error.lineno or 0, error.msg)]]


def validate_bytes(data: bytes, label: str, suffix: str) -> list[str]:
    """Validate one SSP document held in memory; ``suffix`` (``.ssd``, ``.ssv``, ...) says which root it must have."""
    if suffix not in ROOTS:
        raise ValueError(f"suffix = {suffix!r} is invalid: must be one of {', '.join(ROOTS)}")
    tree, problems = _parse(data, label)
    if tree is None:
        return problems
    root = tree.getroot()
    if root.tag != ROOTS[suffix]:
        return [f"{label}:{root.sourceline}: root element is {_short(root.tag)}, "
                f"a {suffix} file must hold {_short(ROOTS[suffix])}"]
    schema = _schema()
    if not schema.validate(tree):
        problems += [f"{label}:{e.line}: {_short(e.message)}" for e in schema.error_log]
    return problems


def _short(message: str) -> str:
    """``{http://ssp-standard.org/SSP1/SystemStructureDescription}Component`` -> ``ssd:Component``."""
    for namespace, (_, prefix) in SCHEMAS.items():
        message = message.replace(f"{{{namespace}}}", f"{prefix}:")
    return message


def validate(path: str | Path) -> list[str]:
    """Validate an ``.ssd``/``.ssv``/``.ssm``/``.ssb`` file, or an ``.ssp`` archive, against the SSP 1.0 schemas.

    For an archive: ``SystemStructure.ssd`` must be at its root; every SSP document in it is
    validated; every ``source`` of a component or parameter binding in a root SSD that names a
    member of the archive must exist.

    Returns
    -------
    list of str
        ``"<file>:<line>: <message>"`` per problem; empty if valid.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such SSP file: {path}")
    suffix = path.suffix.lower()
    if suffix == ".ssp":
        return _validate_archive(path)
    if suffix not in ROOTS:
        raise ValueError(f"path = {str(path)!r} is invalid: must end in .ssp, {', '.join(ROOTS)}")
    return validate_bytes(path.read_bytes(), str(path), suffix)


def _validate_archive(path: Path) -> list[str]:
    try:
        archive = zipfile.ZipFile(path)
    except zipfile.BadZipFile as error:
        return [f"{path}:0: not a zip archive: {error}"]
    problems: list[str] = []
    with archive:
        names = set(archive.namelist())
        if DEFAULT_SSD not in names:
            problems.append(f"{path}:0: no {DEFAULT_SSD} at the root of the archive")
        for name in sorted(names):
            suffix = PurePosixPath(name).suffix.lower()
            if suffix not in ROOTS:
                continue
            label = f"{path}!{name}"
            data = archive.read(name)
            problems += validate_bytes(data, label, suffix)
            if suffix == ".ssd" and "/" not in name:
                problems += _missing_sources(data, label, names)
    return problems


def _missing_sources(data: bytes, label: str, names: set[str]) -> list[str]:
    tree, _ = _parse(data, label)
    if tree is None:
        return []
    problems = []
    for element in tree.iter(f"{{{SSD_NS}}}Component", f"{{{SSD_NS}}}ParameterBinding"):
        source = element.get("source")
        if not source or "://" in source or source.startswith(("#", "/")):
            continue
        member = source.split("#", 1)[0]
        if member not in names:
            problems.append(f"{label}:{element.sourceline}: source {source!r} is not in the archive")
    return problems


# --- portability to OSP libcosim ------------------------------------------------------------------

def libcosim_portability(path: str | Path) -> list[str]:
    """What OSP libcosim's SSP loader would reject or read differently in an ``.ssd`` or ``.ssp``.

    libcosim (ssp_parser.cpp, libcosimpy 0.0.6) reads XML with boost::property_tree, so it matches
    the literal prefixes ``ssd:``, ``ssc:``, ``ssv:`` and ``osp:``; it takes every child of
    ``ssd:Elements`` as a component with a ``source``; it cannot load connections to or from
    system connectors; it aborts on Enumeration and Binary connectors; and it applies only the
    first ``ssd:ParameterBinding`` of each component (later ones are parsed, then ignored).
    The last is reported as a note, since :func:`nfal.orchestration.libcosim.run_ssp` applies
    the others itself.

    Returns
    -------
    list of str
        ``"<file>:<line>: <message>"`` per problem; empty if libcosim loads it as written.
    """
    path = Path(path)
    archive = zipfile.ZipFile(path) if path.suffix.lower() == ".ssp" else None
    try:
        if archive is not None:
            label, data = f"{path}!{DEFAULT_SSD}", archive.read(DEFAULT_SSD)
        else:
            label, data = str(path), path.read_bytes()
        tree, problems = _parse(data, label)
        if tree is None:
            return problems
        problems += _prefix_problems(tree, label)
        # The parameter sets the bindings reference (relative to the SSD, at the archive's root).
        for source in sorted({b.get("source") for b in tree.iter(f"{{{SSD_NS}}}ParameterBinding") if b.get("source")}):
            if archive is not None:
                if source not in archive.namelist():
                    continue  # validate() reports missing members
                ssv_label, text = f"{path}!{source}", archive.read(source)
            else:
                file = path.parent / source
                if not file.is_file():  # an SSD in the source tree: its sets lie beside it (ssp_archive.pack)
                    file = path.parent / PurePosixPath(source).name
                if not file.is_file():
                    continue
                ssv_label, text = str(file), file.read_bytes()
            ssv_tree, ssv_problems = _parse(text, ssv_label)
            problems += ssv_problems if ssv_tree is None else _prefix_problems(ssv_tree, ssv_label)
    finally:
        if archive is not None:
            archive.close()
    root = tree.getroot()
    system = root.find(f"{{{SSD_NS}}}System")
    if system is None:
        return problems
    elements = system.find(f"{{{SSD_NS}}}Elements")
    for child in [] if elements is None else elements:
        if not isinstance(child.tag, str):
            continue
        if child.tag != f"{{{SSD_NS}}}Component":
            problems.append(f"{label}:{child.sourceline}: {etree.QName(child).localname} in ssd:Elements: "
                            "libcosim reads every element there as an FMU component")
            continue
        if not child.get("source"):
            problems.append(f"{label}:{child.sourceline}: component {child.get('name')!r} has no source")
        for kind in ("Enumeration", "Binary"):
            for node in child.iter(f"{{{SSC_NS}}}{kind}"):
                problems.append(f"{label}:{node.sourceline}: {kind} connector: libcosim aborts on it")
        bindings = child.findall(f"{{{SSD_NS}}}ParameterBindings/{{{SSD_NS}}}ParameterBinding")
        for binding in bindings:
            if binding.get("prefix"):
                problems.append(f"{label}:{binding.sourceline}: ParameterBinding prefix is ignored by libcosim")
            if binding.find(f"{{{SSD_NS}}}ParameterMapping") is not None:
                problems.append(f"{label}:{binding.sourceline}: ParameterMapping is ignored by libcosim")
        if len(bindings) > 1:
            problems.append(
                f"{label}:{bindings[1].sourceline}: note: component {child.get('name')!r} has {len(bindings)} "
                "parameter bindings; libcosim applies only the first (run_ssp applies the others)")
    if system.find(f"{{{SSD_NS}}}ParameterBindings") is not None:
        problems.append(f"{label}:{system.sourceline}: system-level ParameterBindings are ignored by libcosim")
    for connection in system.iterfind(f"{{{SSD_NS}}}Connections/{{{SSD_NS}}}Connection"):
        if not connection.get("startElement") or not connection.get("endElement"):
            problems.append(f"{label}:{connection.sourceline}: connection to a system connector: "
                            "libcosim fails to load it ('No such node (<xmlattr>.startElement)')")
    return problems


def _prefix_problems(tree: etree._ElementTree, label: str) -> list[str]:
    problems = []
    for element in tree.iter():
        if not isinstance(element.tag, str):
            continue
        namespace = etree.QName(element).namespace
        if namespace in SCHEMAS and element.prefix != SCHEMAS[namespace][1]:
            problems.append(f"{label}:{element.sourceline}: {etree.QName(element).localname} has prefix "
                            f"{element.prefix!r}; libcosim needs the literal '{SCHEMAS[namespace][1]}:'")
            break
    return problems
