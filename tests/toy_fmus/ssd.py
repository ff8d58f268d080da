"""Writing small SSP 1.0 structures of the toy FMUs for the orchestrator's tests."""

from __future__ import annotations

import shutil
import zipfile
from pathlib import Path

HEADER = ('<?xml version="1.0" encoding="UTF-8"?>\n'
          '<ssd:SystemStructureDescription name="{name}" version="1.0"\n'
          '    xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"\n'
          '    xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon"\n'
          '    xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues">\n')


def connector(name: str, kind: str, unit: str | None = None, type_: str = "Real") -> str:
    unit_attribute = f' unit="{unit}"' if unit else ""
    return f'<ssd:Connector name="{name}" kind="{kind}"><ssc:{type_}{unit_attribute}/></ssd:Connector>'


def parameter_set(values: dict, name: str = "set") -> str:
    """An ssv:ParameterSet of ``name -> (type, value[, unit])``."""
    rows = []
    for key, spec in values.items():
        type_, value, *unit = spec
        unit_attribute = f' unit="{unit[0]}"' if unit else ""
        text = str(value).lower() if isinstance(value, bool) else value
        rows.append(f'<ssv:Parameter name="{key}"><ssv:{type_} value="{text}"{unit_attribute}/></ssv:Parameter>')
    return (f'<ssv:ParameterSet version="1.0" name="{name}"><ssv:Parameters>{"".join(rows)}'
            '</ssv:Parameters></ssv:ParameterSet>')


def ssv_file(values: dict, name: str = "set") -> str:
    return ('<?xml version="1.0" encoding="UTF-8"?>\n' + parameter_set(values, name).replace(
        "<ssv:ParameterSet ", '<ssv:ParameterSet '
        'xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues" '
        'xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon" ', 1))


def bindings(*items: str) -> str:
    """ParameterBindings from items: a file name (``source=``) or an inline parameter set (XML)."""
    parts = []
    for item in items:
        if item.lstrip().startswith("<"):
            parts.append(f"<ssd:ParameterBinding><ssd:ParameterValues>{item}</ssd:ParameterValues></ssd:ParameterBinding>")
        else:
            parts.append(f'<ssd:ParameterBinding source="{item}"/>')
    return f"<ssd:ParameterBindings>{''.join(parts)}</ssd:ParameterBindings>" if parts else ""


def component(name: str, fmu: str, connectors: tuple = (), parameter_bindings: str = "") -> str:
    body = f"<ssd:Connectors>{''.join(connectors)}</ssd:Connectors>" if connectors else ""
    return f'<ssd:Component name="{name}" source="resources/{fmu}.fmu">{body}{parameter_bindings}</ssd:Component>'


def connection(start: str, end: str) -> str:
    """``"Element.connector"`` or a bare system connector name at either end."""
    def attributes(end_: str, which: str) -> str:
        element, _, name = end_.rpartition(".")
        return (f'{which}Element="{element}" ' if element else "") + f'{which}Connector="{name}"'
    return f"<ssd:Connection {attributes(start, 'start')} {attributes(end, 'end')}/>"


def system(name: str, elements: tuple, connections: tuple = (), connectors: tuple = (),
           parameter_bindings: str = "") -> str:
    body = f"<ssd:Connectors>{''.join(connectors)}</ssd:Connectors>" if connectors else ""
    body += parameter_bindings
    body += f"<ssd:Elements>{''.join(elements)}</ssd:Elements>"
    if connections:
        body += f"<ssd:Connections>{''.join(connections)}</ssd:Connections>"
    return f'<ssd:System name="{name}">{body}</ssd:System>'


def ssd(system_xml: str, *, name: str = "toy", stop_time: float | None = None, step_size: float | None = None,
        units: str = "") -> str:
    experiment = ""
    if stop_time is not None:
        annotation = ""
        if step_size is not None:
            annotation = ('<ssd:Annotations><ssc:Annotation type="com.opensimulationplatform"><osp:Algorithm '
                          'xmlns:osp="http://opensimulationplatform.com/SSP/OSPAnnotations"><osp:FixedStepAlgorithm '
                          f'baseStepSize="{step_size}"/></osp:Algorithm></ssc:Annotation></ssd:Annotations>')
        experiment = f'<ssd:DefaultExperiment startTime="0" stopTime="{stop_time}">{annotation}</ssd:DefaultExperiment>'
    units_xml = f"<ssd:Units>{units}</ssd:Units>" if units else ""
    return HEADER.format(name=name) + system_xml + units_xml + experiment + "</ssd:SystemStructureDescription>\n"


def write_folder(folder: Path, ssd_text: str, fmus: dict[str, Path], files: dict[str, str] | None = None) -> Path:
    """An SSP folder: SystemStructure.ssd, the toy FMUs under resources/, and extra text files."""
    folder = Path(folder)
    (folder / "resources").mkdir(parents=True, exist_ok=True)
    for name, path in fmus.items():
        shutil.copy(path, folder / "resources" / f"{name}.fmu")
    (folder / "SystemStructure.ssd").write_text(ssd_text, encoding="utf-8")
    for relative, text in (files or {}).items():
        (folder / relative).parent.mkdir(parents=True, exist_ok=True)
        (folder / relative).write_text(text, encoding="utf-8")
    return folder


def pack(folder: Path, archive: Path) -> Path:
    """Zip an SSP folder into an .ssp archive (SystemStructure.ssd at the root)."""
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as zip_file:
        for path in sorted(Path(folder).rglob("*")):
            if path.is_file():
                zip_file.write(path, path.relative_to(folder).as_posix())
    return archive
