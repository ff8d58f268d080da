"""Reading SSP 1.0 system structures into typed data classes (no FMU is opened here).

:func:`read_ssp` takes an ``.ssp`` archive (a zip with ``SystemStructure.ssd`` at its root), a
folder holding ``SystemStructure.ssd``, or a bare ``.ssd`` file, and returns a
:class:`SystemStructure`: the system with its connectors, elements (FMU components and nested
systems, inline or referenced ``.ssd``/``.ssp``), connections, parameter bindings (inline
``ssv:ParameterSet`` or ``source=`` an ``.ssv`` file, relative to the SSD), the unit definitions and
the default experiment. Paths are resolved and FMU files checked to exist; what the FMUs declare
is checked later, by :func:`nfal.orchestration.resolve.resolve`.

Namespaces (SSP 1.0): ``ssd`` http://ssp-standard.org/SSP1/SystemStructureDescription, ``ssc``
.../SystemStructureCommon, ``ssv`` .../SystemStructureParameterValues. Geometry, graphics and
annotations are ignored, except the OSP annotation ``FixedStepAlgorithm baseStepSize``, read as
the default step size. A connection may carry an ``ssc:LinearTransformation`` (factor, offset).
Valid SSP 1.0 features that are not implemented (signal dictionaries, parameter mappings, the other
connection transformations, parameter connections between elements) raise
:class:`~nfal.errors.UnsupportedFeatureError` rather than being silently dropped.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import math
import os
import tempfile
import urllib.parse
import urllib.request
import zipfile
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path

from lxml import etree

from nfal.errors import MissingFmuError, StructureError, UnknownElementError, UnsupportedFeatureError

logger = logging.getLogger(__name__)

SSD_NS = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC_NS = "http://ssp-standard.org/SSP1/SystemStructureCommon"
SSV_NS = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"
SSB_NS = "http://ssp-standard.org/SSP1/SystemStructureSignalDictionary"
SSM_NS = "http://ssp-standard.org/SSP1/SystemStructureParameterMapping"

#: The SSD at the root of an archive or folder.
DEFAULT_SSD = "SystemStructure.ssd"
CONNECTOR_KINDS = ("input", "output", "inout", "parameter", "calculatedParameter")
TYPES = ("Real", "Integer", "Boolean", "String", "Enumeration", "Binary")
FMU_TYPE = "application/x-fmu-sharedlibrary"
SSD_TYPE = "application/x-ssp-definition"
SSP_TYPE = "application/x-ssp-package"
PARAMETER_SET_TYPE = "application/x-ssp-parameter-set"
#: Exponents of a unit's base units, in this order (FMI 2.0 and SSP 1.0 BaseUnit attributes).
#: Most bytes an .ssp archive may unpack to (the Fig. 7 archives: about 30 MiB), and an SSD or SSV may hold.
MAX_UNPACKED_BYTES = 1 << 30
MAX_XML_BYTES = 64 << 20
#: Deepest nesting of SSDs referencing SSDs (a structure that references itself through copies stops here).
MAX_NESTING = 16

BASE_UNITS = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")


@dataclasses.dataclass(frozen=True)
class Unit:
    """A unit definition (``ssc:Unit``): SI base-unit exponents, factor and offset.

    A value v in this unit is ``factor * v + offset`` in the base units.
    """

    name: str
    exponents: tuple[int, ...] = (0,) * len(BASE_UNITS)
    factor: float = 1.0
    offset: float = 0.0

    def same_as(self, other: "Unit") -> bool:
        """True when a value means the same in both units (same dimensions, factor and offset)."""
        return (self.exponents == other.exponents and abs(self.factor - other.factor) <= 1e-12 * abs(self.factor)
                and abs(self.offset - other.offset) <= 1e-12 * max(1.0, abs(self.offset)))


@dataclasses.dataclass(frozen=True)
class Connector:
    """A connector of a system or component: ``kind`` is one of :data:`CONNECTOR_KINDS`.

    ``type`` (Real, Integer, Boolean, String, Enumeration, Binary) and ``unit`` are None where the SSD
    leaves them to the FMU.
    """

    name: str
    kind: str
    type: str | None = None
    unit: str | None = None


@dataclasses.dataclass(frozen=True)
class ParameterValue:
    """One ``ssv:Parameter``: its name, type and value (float, int, bool or str), and its unit."""

    name: str
    type: str
    value: float | int | bool | str
    unit: str | None = None


@dataclasses.dataclass(frozen=True)
class ParameterSet:
    """An ``ssv:ParameterSet``: values in file order; ``source`` is the .ssv file (None: inline)."""

    name: str
    values: tuple[ParameterValue, ...]
    units: Mapping[str, Unit] = dataclasses.field(default_factory=dict)
    source: Path | None = None


@dataclasses.dataclass(frozen=True)
class ParameterBinding:
    """An ``ssd:ParameterBinding``: the parameter set and the ``prefix`` prepended to its names."""

    parameter_set: ParameterSet
    prefix: str = ""

    @property
    def origin(self) -> str:
        """Where the values come from, for messages: the .ssv file name or ``inline set 'name'``."""
        source = self.parameter_set.source
        return source.name if source is not None else f"inline set {self.parameter_set.name!r}"


@dataclasses.dataclass(frozen=True)
class LinearTransformation:
    """``ssc:LinearTransformation`` of a connection: the target receives ``factor * source + offset``.

    Applied in the direction of the data flow, as OSP libcosim does.
    """

    factor: float = 1.0
    offset: float = 0.0

    def then(self, later: "LinearTransformation") -> "LinearTransformation":
        """This transformation followed by ``later`` (a chain of connections through system connectors)."""
        return LinearTransformation(later.factor * self.factor, later.factor * self.offset + later.offset)


@dataclasses.dataclass(frozen=True)
class Connection:
    """An ``ssd:Connection``. An element of None means a connector of the enclosing system.

    Start and end do not give the direction of the data flow (SSP 1.0): the connectors' kinds do.
    ``transformation`` is the connection's ``ssc:LinearTransformation``, if any.
    """

    start_element: str | None
    start_connector: str
    end_element: str | None
    end_connector: str
    transformation: LinearTransformation | None = None

    @property
    def start(self) -> str:
        return f"{self.start_element}.{self.start_connector}" if self.start_element else self.start_connector

    @property
    def end(self) -> str:
        return f"{self.end_element}.{self.end_connector}" if self.end_element else self.end_connector


@dataclasses.dataclass(frozen=True)
class Component:
    """An FMU component: ``source`` is the resolved path of the .fmu (or of an extracted FMU folder)."""

    name: str
    source: Path
    connectors: tuple[Connector, ...] = ()
    parameter_bindings: tuple[ParameterBinding, ...] = ()
    implementation: str = "any"

    def connector(self, name: str) -> Connector | None:
        return next((c for c in self.connectors if c.name == name), None)


@dataclasses.dataclass(frozen=True)
class System:
    """An ``ssd:System``: its connectors, elements (components and nested systems), connections, bindings."""

    name: str
    connectors: tuple[Connector, ...] = ()
    elements: tuple["Component | System", ...] = ()
    connections: tuple[Connection, ...] = ()
    parameter_bindings: tuple[ParameterBinding, ...] = ()

    def connector(self, name: str) -> Connector | None:
        return next((c for c in self.connectors if c.name == name), None)

    def element(self, name: str) -> "Component | System | None":
        return next((e for e in self.elements if e.name == name), None)

    def components(self, prefix: str = "") -> Iterator[tuple[str, Component]]:
        """Every FMU component, depth first, with its hierarchical name (``Sub.Plant``)."""
        for element in self.elements:
            if isinstance(element, System):
                yield from element.components(f"{prefix}{element.name}.")
            else:
                yield f"{prefix}{element.name}", element


@dataclasses.dataclass(frozen=True)
class DefaultExperiment:
    """``ssd:DefaultExperiment`` [s]; ``step_size`` from the OSP ``FixedStepAlgorithm`` annotation."""

    start_time: float | None = None
    stop_time: float | None = None
    step_size: float | None = None


@dataclasses.dataclass(eq=False)
class SystemStructure:
    """A read system structure. Archives are unpacked to a temporary folder, removed by :meth:`close`
    (or when the object is garbage collected); use it as a context manager.

    Attributes
    ----------
    name : str
        The SSD's ``name``.
    system : System
    units : dict of str to Unit
        The SSD's unit definitions (``ssd:Units``).
    default_experiment : DefaultExperiment
    path : Path
        What was read (archive, folder or .ssd).
    ssd_path : Path
        The SSD file (inside the unpacked archive for an .ssp).
    """

    name: str
    system: System
    units: dict[str, Unit]
    default_experiment: DefaultExperiment
    path: Path
    ssd_path: Path
    _temporary: list = dataclasses.field(default_factory=list, repr=False)

    def close(self) -> None:
        """Remove the unpacked archive(s), if any."""
        for holder in self._temporary:
            holder.cleanup()
        self._temporary.clear()

    def __enter__(self) -> "SystemStructure":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def read_ssp(path: str | os.PathLike, *, ssd_name: str = DEFAULT_SSD) -> SystemStructure:
    """Read an SSP 1.0 system structure.

    Parameters
    ----------
    path : path-like
        An ``.ssp`` archive, a folder with ``ssd_name`` in it, or an ``.ssd`` file.
    ssd_name : str
        The SSD inside an archive or folder (default ``SystemStructure.ssd``).

    Raises
    ------
    StructureError
        Not an SSP 1.0 structure, or inconsistent (names the element or connector).
    MissingFmuError
        A component's FMU is not where its ``source`` says.
    UnsupportedFeatureError
        A valid SSP 1.0 feature this reader does not implement.
    """
    path = Path(path)
    temporary: list = []
    try:
        ssd_path = _locate_ssd(path, ssd_name, temporary)
        reader = _SsdReader(temporary, lambda text: _as_given(text, temporary, path))
        structure = reader.read(ssd_path)
    except BaseException as exc:
        for holder in temporary:
            holder.cleanup()
        if isinstance(exc, StructureError) and len(exc.args) == 1 and isinstance(exc.args[0], str):
            exc.args = (_as_given(exc.args[0], temporary, path),)
        raise
    structure.path = path
    structure._temporary.extend(temporary)
    logger.info("read %s: system %r with %d components", path, structure.system.name,
                sum(1 for _ in structure.system.components()))
    return structure


def _as_given(text: str, temporary: list, path: Path) -> str:
    """``text`` naming the archive ``path`` where it names the folder the archive was unpacked to (deleted when the
    structure closes: the user's archive is what a message must name)."""
    if not temporary:
        return text
    folder = str(Path(temporary[0].name).resolve())
    return text.replace(folder + os.sep, f"{path}: ").replace(folder, str(path))


#: Warnings given in this process (:meth:`_SsdReader._warn_once`).
_WARNED: set[str] = set()


def _locate_ssd(path: Path, ssd_name: str, temporary: list) -> Path:
    if path.is_dir():
        ssd = path / ssd_name
        if not ssd.is_file():
            raise StructureError(f"{path}: a folder without {ssd_name}; "
                                 "expected an SSP folder, .ssp archive or .ssd file")
        return ssd
    if not path.is_file():
        raise StructureError(f"{path}: not a regular file" if path.exists() else f"{path}: no such file or folder")
    if zipfile.is_zipfile(path):
        holder = tempfile.TemporaryDirectory(prefix="nfal-ssp-", ignore_cleanup_errors=True)  # removed when collected
        temporary.append(holder)
        folder = Path(holder.name)
        try:
            with zipfile.ZipFile(path) as archive:
                _check_archive(path, archive)
                entries = archive.infolist()
                for entry in entries:  # Windows PowerShell 5's Compress-Archive writes \ where the zip format says /
                    entry.filename = entry.filename.replace("\\", "/")
                archive.extractall(folder, members=entries)
        except (zipfile.BadZipFile, OSError, NotImplementedError, RuntimeError) as exc:
            # NotImplementedError: a compression method zipfile lacks; RuntimeError: an encrypted entry
            raise StructureError(f"{path}: cannot unpack the SSP archive: {exc}") from None
        ssd = folder / ssd_name
        if not ssd.is_file():
            raise StructureError(f"{path}: the archive has no {ssd_name} at its root")
        return ssd
    if path.suffix.lower() == ".ssp":  # read as an SSD it would be "not well-formed XML", which misleads
        raise StructureError(f"{path}: not an .ssp archive (a zip file): damaged, cut short, or not an archive")
    return path


def _check_archive(path: Path, archive: zipfile.ZipFile) -> None:
    """Refuse, before unpacking, an archive with encrypted entries or more than MAX_UNPACKED_BYTES in all."""
    entries = archive.infolist()
    encrypted = [entry.filename for entry in entries if entry.flag_bits & 0x1]
    if encrypted:
        raise StructureError(f"{path}: encrypted entries ({', '.join(encrypted[:3])}); SSP archives are not encrypted")
    total = sum(entry.file_size for entry in entries)
    if total > MAX_UNPACKED_BYTES:
        raise StructureError(f"{path}: unpacks to {total / 2**20:,.0f} MiB, "
                             f"more than the {MAX_UNPACKED_BYTES / 2**20:,.0f} MiB an SSP archive may hold "
                             "(FMUs are a few MiB); unzip it yourself and run the folder if it is right")


def _refuse_repeated(names: list[str], what: str, why: str = "") -> None:
    """Raise StructureError ``<what> named <the names given more than once><why>``, if any are."""
    repeated = sorted(name for name, count in collections.Counter(names).items() if count > 1)
    if repeated:
        raise StructureError(f"{what} named {', '.join(map(repr, repeated))}{why}")


def _q(namespace: str, tag: str) -> str:
    return f"{{{namespace}}}{tag}"


def _parse_xml(path: Path, what: str):
    if not path.is_file():
        raise StructureError(f"{path}: the {what} is not a regular file")
    if path.stat().st_size > MAX_XML_BYTES:
        raise StructureError(f"{path}: {path.stat().st_size / 2**20:,.0f} MiB, more than the {MAX_XML_BYTES >> 20} MiB "
                             f"a {what} may hold")
    try:
        return etree.parse(str(path), etree.XMLParser(remove_comments=True, resolve_entities=False)).getroot()
    except OSError as exc:
        raise StructureError(f"{path}: cannot read the {what}: {exc}") from None
    except etree.XMLSyntaxError as exc:
        if "XML_PARSE_HUGE" in str(exc):  # libxml2's limits, kept: they are what stops an XML bomb
            raise StructureError(f"{path}: a text or attribute of the {what} is longer than the 10 MB the XML reader "
                                 f"takes (line {exc.lineno}): cut what is that long (an annotation?)") from None
        raise StructureError(f"{path}: not well-formed XML ({what}): {exc}") from None


def _resolve_uri(uri: str, base: Path, where: str) -> Path:
    """A ``source`` URI (relative reference or ``file:`` URI) as a path; relative to the folder ``base``."""
    parsed = urllib.parse.urlparse(uri)
    if parsed.scheme == "file":  # file:///abs/x.fmu; file:x.fmu (no slash) is relative, to the SSD as any reference
        path = Path(urllib.request.url2pathname(parsed.path))
        return path if path.is_absolute() or parsed.netloc else base / path
    if len(parsed.scheme) > 1:  # one letter: a Windows drive
        raise UnsupportedFeatureError(f"{where}: source {uri!r}: only relative paths and file: URIs are supported")
    return base / urllib.parse.unquote(uri)


def _float(text: str | None, where: str) -> float | None:
    if text is None:
        return None
    try:
        value = float(text)
    except ValueError:
        raise StructureError(f"{where}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise StructureError(f"{where}: {text!r}; must be a finite number")
    return value


def parse_boolean(text: str) -> bool | None:
    """``text`` as a Boolean (true, false, 1 or 0, any case, spaces around), or None: the one reading of a Boolean
    written as text, in an SSD, an .ssv, a ``--param`` or a libcosim parameter."""
    return {"true": True, "1": True, "false": False, "0": False}.get(text.strip().lower())


def _boolean(text: str, where: str) -> bool:
    value = parse_boolean(text)
    if value is None:
        raise StructureError(f"{where}: {text!r} is not a Boolean (true, false, 1 or 0)")
    return value


def _read_units(parent, where: str) -> dict[str, Unit]:
    """``ssc:Unit`` children of ``parent`` (an ``ssd:Units`` or ``ssv:Units``), by name."""
    units: dict[str, Unit] = {}
    if parent is None:
        return units
    for element in parent.iter(_q(SSC_NS, "Unit")):
        name = element.get("name")
        base = element.find(_q(SSC_NS, "BaseUnit"))
        if base is None:  # says nothing about the dimensions: compared by name only
            continue
        try:
            exponents = tuple(int(base.get(b, "0")) for b in BASE_UNITS)
        except ValueError:
            raise StructureError(f"{where}: unit {name!r} has a non-integer base-unit exponent") from None
        units[name] = Unit(name, exponents, _float(base.get("factor", "1"), f"{where}: unit {name!r}"),
                           _float(base.get("offset", "0"), f"{where}: unit {name!r}"))
    return units


def read_parameter_set(element, *, source: Path | None = None, where: str = "") -> ParameterSet:
    """Parse an ``ssv:ParameterSet`` element (of an .ssv file, or inline in a binding)."""
    where = where or (str(source) if source else "ParameterSet")
    if element.tag != _q(SSV_NS, "ParameterSet"):
        raise StructureError(f"{where}: expected an ssv:ParameterSet ({SSV_NS}), "
                             f"found {etree.QName(element).localname} "
                             f"in namespace {etree.QName(element).namespace!r}")
    values = []
    parameters = element.find(_q(SSV_NS, "Parameters"))
    for parameter in (parameters if parameters is not None else ()):
        if parameter.tag != _q(SSV_NS, "Parameter"):
            continue
        name = parameter.get("name")
        typed = next((child for child in parameter if etree.QName(child).namespace == SSV_NS
                      and etree.QName(child).localname in TYPES), None)
        if name is None or typed is None:
            raise StructureError(f"{where}, line {parameter.sourceline}: a parameter needs a name and a type element")
        kind, text = etree.QName(typed).localname, typed.get("value")
        here = f"{where}: parameter {name!r}"
        if text is None:
            raise StructureError(f"{here}: no value")
        if kind == "Real":
            value = _float(text, here)
        elif kind == "Integer":
            try:
                value = int(text)
            except ValueError:
                raise StructureError(f"{here}: {text!r} is not an integer") from None
        elif kind == "Boolean":
            value = _boolean(text, here)
        elif kind == "Binary":
            raise UnsupportedFeatureError(f"{here}: Binary parameter values are not supported")
        else:  # String; Enumeration: the item name, looked up in the FMU later
            value = text
        if any(earlier.name == name for earlier in values):
            raise StructureError(f"{here}, line {parameter.sourceline}: given twice in one parameter set (which "
                                 "value is meant?)")
        values.append(ParameterValue(name, kind, value, typed.get("unit") if kind == "Real" else None))
    return ParameterSet(element.get("name", source.stem if source else "inline"), tuple(values),
                        _read_units(element.find(_q(SSV_NS, "Units")), where), source)


class _SsdReader:
    """Reads one SSD and, recursively, the SSDs its components reference."""

    def __init__(self, temporary: list, as_given: Callable[[str], str] = str) -> None:
        self.temporary, self.as_given = temporary, as_given
        self.units: dict[str, Unit] = {}
        self._stack: list[Path] = []

    def read(self, ssd_path: Path) -> SystemStructure:
        ssd_path = ssd_path.resolve()
        if len(self._stack) >= MAX_NESTING:
            raise StructureError(f"{ssd_path}: nested more than {MAX_NESTING} deep "
                                 f"({' -> '.join(p.name for p in self._stack)})")
        if ssd_path in self._stack:
            raise StructureError(f"{ssd_path}: references itself (through {' -> '.join(p.name for p in self._stack)})")
        self._stack.append(ssd_path)
        try:
            root = _parse_xml(ssd_path, "system structure description")
            if root.tag != _q(SSD_NS, "SystemStructureDescription"):
                raise StructureError(
                    f"{ssd_path}: not an SSP 1.0 system structure: the root element is {etree.QName(root).localname!r} "
                    f"in namespace {etree.QName(root).namespace!r}, expected SystemStructureDescription in {SSD_NS!r}")
            version = root.get("version", "")
            if not version.startswith("1."):
                self._warn_once(f"{ssd_path}: SSP version {version!r}; reading it as SSP 1.0")
            units = _read_units(root.find(_q(SSD_NS, "Units")), str(ssd_path))
            self._merge_units(units, ssd_path)
            system_element = root.find(_q(SSD_NS, "System"))
            if system_element is None:
                raise StructureError(f"{ssd_path}: no ssd:System")
            system = self._system(system_element, ssd_path.parent, ssd_path.name)
            if len(self._stack) == 1:  # the whole tree read: its hierarchical names
                _refuse_repeated([name for name, _ in system.components()], f"{ssd_path.name}: more than one element",
                                 " by its hierarchical name (a dot in an element's name meets a sub-system's)")
            return SystemStructure(root.get("name", system.name), system, dict(self.units),
                                   self._default_experiment(root, ssd_path), ssd_path, ssd_path)
        finally:
            self._stack.pop()

    def _warn_once(self, text: str) -> None:
        """Log ``text`` (naming the user's archive) once in this process: a command may read its structure twice."""
        text = self.as_given(text)
        if text not in _WARNED:
            _WARNED.add(text)
            logger.warning("%s", text)

    def _inside_archive(self, path: Path, base: Path, where: str) -> Path:
        """``path``, unless an SSD unpacked from an archive (``base`` in its folder) points outside that archive."""
        for holder in self.temporary:
            root = Path(holder.name).resolve()
            if base.resolve().is_relative_to(root) and not path.resolve().is_relative_to(root):
                raise StructureError(f"{where}: {path} is outside the .ssp archive; an archive loads only its own "
                                     "files (unzip it to a folder to use files beside it)")
        return path

    def _merge_units(self, units: Mapping[str, Unit], where: Path) -> None:
        for name, unit in units.items():
            known = self.units.setdefault(name, unit)
            if not known.same_as(unit):
                raise StructureError(f"{where}: unit {name!r} is defined twice, differently")

    @staticmethod
    def _default_experiment(root, ssd_path: Path) -> DefaultExperiment:
        element = root.find(_q(SSD_NS, "DefaultExperiment"))
        if element is None:
            return DefaultExperiment()
        where = f"{ssd_path.name}: DefaultExperiment"
        step = None
        for annotation in element.iter():
            if isinstance(annotation.tag, str) and etree.QName(annotation).localname == "FixedStepAlgorithm":
                step = _float(annotation.get("baseStepSize"), where)
        return DefaultExperiment(_float(element.get("startTime"), where), _float(element.get("stopTime"), where), step)

    def _system(self, element, base: Path, where: str) -> System:
        name = element.get("name")
        if not name:
            raise StructureError(f"{where}, line {element.sourceline}: a system without a name")
        where = f"{where}: system {name!r}"
        if element.find(_q(SSD_NS, "SignalDictionaries")) is not None:
            raise UnsupportedFeatureError(f"{where}: signal dictionaries (ssd:SignalDictionaries) are not supported")
        connectors = self._connectors(element, where)
        elements: list[Component | System] = []
        container = element.find(_q(SSD_NS, "Elements"))
        for child in (container if container is not None else ()):
            if not isinstance(child.tag, str):
                continue
            localname = etree.QName(child).localname
            if localname == "Component":
                elements.append(self._component(child, base, where))
            elif localname == "System":
                elements.append(self._system(child, base, where))
            elif localname == "SignalDictionaryReference":
                raise UnsupportedFeatureError(f"{where}: element {child.get('name')!r}: signal dictionary references "
                                              "are not supported")
        _refuse_repeated([e.name for e in elements], f"{where}: more than one element")
        system = System(name, connectors, tuple(elements), (), self._bindings(element, base, where))
        connections = tuple(self._connection(c, system, where)
                            for c in element.iterfind(f"{_q(SSD_NS, 'Connections')}/{_q(SSD_NS, 'Connection')}"))
        return dataclasses.replace(system, connections=connections)

    def _connectors(self, element, where: str) -> tuple[Connector, ...]:
        connectors = []
        for connector in element.iterfind(f"{_q(SSD_NS, 'Connectors')}/{_q(SSD_NS, 'Connector')}"):
            name, kind = connector.get("name"), connector.get("kind")
            if not name:
                raise StructureError(f"{where}, line {connector.sourceline}: a connector without a name")
            if kind not in CONNECTOR_KINDS:
                raise StructureError(f"{where}: connector {name!r} has kind {kind!r}; must be one of {CONNECTOR_KINDS}")
            typed = next((c for c in connector if isinstance(c.tag, str) and etree.QName(c).namespace == SSC_NS
                          and etree.QName(c).localname in TYPES), None)
            kind_type = etree.QName(typed).localname if typed is not None else None
            unit = typed.get("unit") if typed is not None and kind_type == "Real" else None
            connectors.append(Connector(name, kind, kind_type, unit))
        _refuse_repeated([c.name for c in connectors], f"{where}: more than one connector")
        return tuple(connectors)

    def _component(self, element, base: Path, where: str) -> Component | System:
        name, source = element.get("name"), element.get("source")
        if not name or not source:
            raise StructureError(f"{where}, line {element.sourceline}: a component needs a name and a source")
        here = f"{where}: element {name!r}"
        kind = element.get("type", FMU_TYPE)
        path = self._inside_archive(_resolve_uri(source, base, here), base, here)
        if kind in (SSD_TYPE, SSP_TYPE) or path.suffix.lower() in (".ssd", ".ssp"):
            return self._referenced_system(element, name, path, here)
        if kind != FMU_TYPE:
            raise UnsupportedFeatureError(f"{here}: component type {kind!r}; "
                                          f"only FMUs ({FMU_TYPE}) and SSDs are supported")
        if not path.exists():
            raise MissingFmuError(f"{here}: FMU {source!r} not found (looked for {path})")
        if not (path.is_file() or path.is_dir()):
            raise StructureError(f"{here}: FMU {source!r} ({path}) is not a regular file nor an unpacked FMU folder")
        implementation = element.get("implementation", "any")
        if implementation == "ModelExchange":
            raise UnsupportedFeatureError(f"{here}: implementation='ModelExchange'; only co-simulation FMUs are run")
        return Component(name, path, self._connectors(element, here), self._bindings(element, base, here),
                         implementation)

    def _referenced_system(self, element, name: str, path: Path, where: str) -> System:
        """A component that references another SSD/SSP: that system, renamed, with the component's bindings last."""
        if not path.exists():
            raise MissingFmuError(f"{where}: system structure {path} not found")
        nested = self.read(_locate_ssd(path, DEFAULT_SSD, self.temporary))
        bindings = nested.system.parameter_bindings + self._bindings(element, path.parent, where)
        return dataclasses.replace(nested.system, name=name, parameter_bindings=bindings)

    def _bindings(self, element, base: Path, where: str) -> tuple[ParameterBinding, ...]:
        bindings = []
        for binding in element.iterfind(f"{_q(SSD_NS, 'ParameterBindings')}/{_q(SSD_NS, 'ParameterBinding')}"):
            kind = binding.get("type", PARAMETER_SET_TYPE)
            if kind != PARAMETER_SET_TYPE:
                raise UnsupportedFeatureError(f"{where}: parameter binding of type {kind!r}; only {PARAMETER_SET_TYPE}")
            if binding.find(_q(SSD_NS, "ParameterMapping")) is not None:
                raise UnsupportedFeatureError(f"{where}: parameter mappings (ssd:ParameterMapping) are not supported")
            source = binding.get("source")
            if source and binding.find(_q(SSD_NS, "ParameterValues")) is not None:
                raise StructureError(f"{where}, line {binding.sourceline}: a parameter binding has a source or inline "
                                     "ssd:ParameterValues, not both (SSP 1.0); make them two bindings")
            if source:
                if binding.get("sourceBase", "SSD") != "SSD":
                    raise UnsupportedFeatureError(f"{where}: parameter binding {source!r} with sourceBase="
                                                  f"{binding.get('sourceBase')!r}; only sources relative to the SSD")
                path = self._inside_archive(_resolve_uri(source, base, where), base, where)
                if not path.is_file():
                    raise StructureError(f"{where}: parameter values {source!r} " + (
                        f"are not a regular file ({path})" if path.exists() else f"not found (looked for {path})"))
                root = _parse_xml(path, "parameter set")
                parameter_set = read_parameter_set(root, source=path, where=f"{where}: {path.name}")
            else:
                inline = binding.find(_q(SSD_NS, "ParameterValues"))
                sets = [] if inline is None else [c for c in inline if isinstance(c.tag, str)]
                if len(sets) != 1:
                    raise StructureError(f"{where}, line {binding.sourceline}: a parameter binding needs a source or "
                                         "one inline ssv:ParameterSet in ssd:ParameterValues")
                parameter_set = read_parameter_set(sets[0], where=f"{where}: inline parameter set")
            bindings.append(ParameterBinding(parameter_set, binding.get("prefix", "")))
        return tuple(bindings)

    @staticmethod
    def _connection(element, system: System, where: str) -> Connection:
        connection = Connection(element.get("startElement"), element.get("startConnector", ""),
                                element.get("endElement"), element.get("endConnector", ""))
        here = f"{where}: connection {connection.start} -> {connection.end}"
        if not connection.start_connector or not connection.end_connector:
            raise StructureError(f"{here}, line {element.sourceline}: startConnector and endConnector are required")
        transformation = _transformation(element, here)
        if transformation is not None:
            connection = dataclasses.replace(connection, transformation=transformation)
        for owner, connector in ((connection.start_element, connection.start_connector),
                                 (connection.end_element, connection.end_connector)):
            if owner is None:
                if system.connector(connector) is None:
                    raise UnknownElementError(f"{here}: the system has no connector {connector!r}")
                continue
            target = system.element(owner)
            if target is None:
                raise UnknownElementError(f"{here}: no element named {owner!r} (elements: "
                                          f"{', '.join(e.name for e in system.elements) or 'none'})")
            if isinstance(target, System) and target.connector(connector) is None:
                raise UnknownElementError(f"{here}: system {owner!r} has no connector {connector!r}")
        return connection


def _transformation(connection, where: str) -> LinearTransformation | None:
    """The ``ssc:LinearTransformation`` child of an ``ssd:Connection``; other transformations are refused."""
    found = None
    for child in connection:
        if not (isinstance(child.tag, str) and etree.QName(child).localname.endswith("Transformation")):
            continue
        if child.tag != _q(SSC_NS, "LinearTransformation"):
            raise UnsupportedFeatureError(f"{where}: {etree.QName(child).localname} is not supported (only "
                                          "ssc:LinearTransformation)")
        if found is not None:
            raise StructureError(f"{where}, line {child.sourceline}: a second LinearTransformation (a connection has "
                                 "at most one: write their composition)")
        found = LinearTransformation(_float(child.get("factor", "1"), f"{where}: LinearTransformation factor"),
                                     _float(child.get("offset", "0"), f"{where}: LinearTransformation offset"))
    return found
