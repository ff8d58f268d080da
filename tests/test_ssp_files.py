"""The system structures of ssp/ (Fig. 7) and their parameter sets: schema validity, content per the
contract (docs/cosimulation.md), portability to OSP libcosim, and the packer and validator themselves."""

from __future__ import annotations

import copy
import re
import zipfile
from pathlib import Path

import pytest
from helpers.properties import examples
from hypothesis import HealthCheck, given
from hypothesis import strategies as st
from lxml import etree

from nfal.apps.build import structure_sources
from nfal.fmus.controller import Controller
from nfal.fmus.resonance_tracker import ResonanceTracker
from nfal.fmus.sensor_chain import SensorChain
from nfal.fmus.slow_plant import SlowPlant
from nfal.errors import MissingFmuError, StructureError
from nfal.orchestration.ssp_archive import pack, referenced_resources
from nfal.orchestration.ssp_schema import (SSC_NS, SSD_NS, SSV_NS, libcosim_portability, schema_dir, validate,
                                           validate_bytes)

SSP_DIR = structure_sources()
SSP_FILES = sorted(p.name for p in SSP_DIR.iterdir() if p.suffix in (".ssd", ".ssv"))
STRUCTURES = {"fig7_slow.ssd": "SlowPlant.fmu", "fig7_reynolds.ssd": "ReynoldsPlant.fmu"}
FMU_NAMES = ("SlowPlant", "ReynoldsPlant", "Controller", "ResonanceTracker", "SensorChain", "HardwareProxy",
             "ReferenceGenerator")
RIG_STRUCTURES = {"rig_slow.ssd": "SlowPlant.fmu", "rig_reynolds.ssd": "ReynoldsPlant.fmu"}
D, C, V = f"{{{SSD_NS}}}", f"{{{SSC_NS}}}", f"{{{SSV_NS}}}"

FIG7_CONNECTIONS = {
    ("Controller", "drive_voltage", "ResonanceTracker", "drive_voltage"),
    ("ResonanceTracker", "excitation_amplitude", "Plant", "excitation_amplitude"),
    ("ResonanceTracker", "drive_frequency", "Plant", "drive_frequency"),
    ("Plant", "height", "SensorChain", "true_height"),
    ("SensorChain", "measured_height", "Controller", "measured_height"),
    ("ReferenceGenerator", "reference", "Controller", "reference"),
}
PAPER_RIG = {"mass": 0.1347, "radius": 0.05, "nominal_frequency": 28500.0, "viscosity": 1.81e-5,
             "ambient_pressure": 101325.0, "gravity": 9.81, "calibration": "paper"}
TABLE2 = {"sample_rate": 2000.0, "closed_loop_cutoff": 10.0, "filter_cutoff": 300.0, "analog_cutoff": 2000.0,
          "noise_peak": 2e-6, "noise_cutoff": 300.0, "resonance_frequency": 28500.0, "quality_factor": 500.0,
          "metres_per_volt": 1e-7, "transducer_dynamics": True, "pll_enabled": True, "pll_rate": 2000.0}
BINDINGS = {"Plant": ["paper_rig.ssv"], "Controller": ["paper_rig.ssv", "table2.ssv"],
            "ResonanceTracker": ["table2.ssv"], "SensorChain": ["table2.ssv"]}
#: The Reynolds loop's controller is designed on the film it controls (docs/cosimulation.md).
EXTRA_BINDINGS = {"fig7_slow.ssd": [], "fig7_reynolds.ssd": ["reynolds_design.ssv"]}
#: The ReferenceGenerator's binding: none (its defaults are the paper's staircase) or the loop's own staircase.
REFERENCE_BINDINGS = {"fig7_slow.ssd": [], "fig7_reynolds.ssd": ["reference_reynolds.ssv"]}


def _root(name: str) -> etree._Element:
    return etree.parse(str(SSP_DIR / name)).getroot()


def _parameters(name: str) -> dict:
    values = {}
    for parameter in _root(name).iterfind(f"{V}Parameters/{V}Parameter"):
        typed = parameter[0]
        kind, text = etree.QName(typed).localname, typed.get("value")
        values[parameter.get("name")] = {"Real": float, "Integer": int, "String": str,
                                         "Boolean": lambda s: s == "true"}[kind](text)
    return values


@pytest.fixture(scope="module")
def fmu_dir(tmp_path_factory) -> Path:
    """Stand-in FMUs: packing and schema validation never open them."""
    folder = tmp_path_factory.mktemp("fmus")
    for name in FMU_NAMES:
        with zipfile.ZipFile(folder / f"{name}.fmu", "w") as fmu:
            fmu.writestr("modelDescription.xml", f'<fmiModelDescription modelName="{name}"/>')
    return folder


@pytest.fixture(scope="module")
def archives(fmu_dir, tmp_path_factory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("ssp")
    return {name: pack(SSP_DIR / name, fmu_dir, out / name.replace(".ssd", ".ssp")) for name in STRUCTURES}


# --- the shipped files --------------------------------------------------------------------------------

def test_the_shipped_files_are_the_expected_ones():
    assert SSP_FILES == ["fig7_hil.ssd", "fig7_reynolds.ssd", "fig7_slow.ssd", "paper_rig.ssv",
                         "reference_reynolds.ssv", "reynolds_design.ssv", "rig_reynolds.ssd", "rig_slow.ssd",
                         "rig_truth.ssv", "table2.ssv"]
    assert sorted(p.name for p in schema_dir().glob("*.xsd")) == [
        "SystemStructureCommon.xsd", "SystemStructureDescription.xsd", "SystemStructureParameterMapping.xsd",
        "SystemStructureParameterValues.xsd", "SystemStructureSignalDictionary.xsd"]


@pytest.mark.parametrize("name", SSP_FILES)
def test_ssp_file_is_valid_ssp_1_0(name):
    assert validate(SSP_DIR / name) == []


@pytest.mark.parametrize("name", SSP_FILES)
def test_ssp_file_uses_the_literal_prefixes_libcosim_needs(name):
    for element in _root(name).iter(etree.Element):
        namespace = etree.QName(element).namespace
        expected = {SSD_NS: "ssd", SSC_NS: "ssc", SSV_NS: "ssv"}.get(namespace)
        assert expected is None or element.prefix == expected, (element.sourceline, element.tag)


@pytest.mark.parametrize("name", STRUCTURES)
def test_structure_is_the_fig7_loop(name):
    root = _root(name)
    components = {c.get("name"): c for c in root.iterfind(f"{D}System/{D}Elements/{D}Component")}
    assert set(components) == {"Plant", "Controller", "ResonanceTracker", "SensorChain", "ReferenceGenerator"}
    assert components["Plant"].get("source") == f"resources/{STRUCTURES[name]}"
    for element in ("Controller", "ResonanceTracker", "SensorChain", "ReferenceGenerator"):
        assert components[element].get("source") == f"resources/{element}.fmu"
    connections = {(c.get("startElement"), c.get("startConnector"), c.get("endElement"), c.get("endConnector"))
                   for c in root.iterfind(f"{D}System/{D}Connections/{D}Connection")}
    assert connections == FIG7_CONNECTIONS
    # Controller.reference is fed by the ReferenceGenerator: the experiment travels with the archive.
    assert "reference" in {c.get("name") for c in components["Controller"].iterfind(f"{D}Connectors/{D}Connector")}
    bindings = {n: [b.get("source").removeprefix("resources/")
                    for b in c.iterfind(f"{D}ParameterBindings/{D}ParameterBinding")] for n, c in components.items()}
    assert bindings == {**BINDINGS, "Controller": BINDINGS["Controller"] + EXTRA_BINDINGS[name],
                        "ReferenceGenerator": REFERENCE_BINDINGS[name]}


@pytest.mark.parametrize("name", STRUCTURES)
def test_every_connector_has_a_declared_si_unit(name):
    root = _root(name)
    units = {u.get("name"): {k: int(v) for k, v in u.find(f"{C}BaseUnit").attrib.items()}
             for u in root.iterfind(f"{D}Units/{C}Unit")}
    assert units["V"] == {"kg": 1, "m": 2, "s": -3, "A": -1} and units["Hz"] == {"s": -1}
    connectors = list(root.iter(f"{D}Connector"))
    reals = [c.find(f"{C}Real") for c in connectors if c.find(f"{C}Real") is not None]
    assert len(reals) >= len(connectors) - 2  # Plant.resting and ResonanceTracker.locked are Boolean
    assert all(real.get("unit") in units for real in reals)
    expected = {"height": "m", "drive_frequency": "Hz", "drive_voltage": "V", "measured_height": "m", "reference": "m"}
    declared = {c.get("name"): c.find(f"{C}Real").get("unit") for c in connectors if c.find(f"{C}Real") is not None}
    assert {k: declared[k] for k in expected} == expected


@pytest.mark.parametrize("name", STRUCTURES)
def test_default_experiment_is_the_staircase_at_2_khz(name):
    experiment = _root(name).find(f"{D}DefaultExperiment")
    assert float(experiment.get("startTime")) == 0.0
    assert float(experiment.get("stopTime")) == pytest.approx(0.1 + 6 * 0.6)
    step = experiment.find(".//{http://opensimulationplatform.com/SSP/OSPAnnotations}FixedStepAlgorithm")
    assert float(step.get("baseStepSize")) == 0.5e-3


def test_swapping_the_plant_is_one_element():
    """... and the Reynolds loop's controller design (one more parameter binding)."""
    slow, reynolds = _root("fig7_slow.ssd"), _root("fig7_reynolds.ssd")

    def without_plant(root):
        root = copy.deepcopy(root)
        for attribute in ("name", "description"):
            root.attrib.pop(attribute)
        elements = root.find(f"{D}System/{D}Elements")
        elements.remove(elements.find(f"{D}Component[@name='Plant']"))
        elements.remove(elements.find(f"{D}Component[@name='ReferenceGenerator']"))  # its staircase differs
        for binding in root.iterfind(f".//{D}ParameterBinding[@source='resources/reynolds_design.ssv']"):
            binding.getparent().remove(binding)
        return re.sub(rb">\s+<", b"><", etree.tostring(root, method="c14n", with_comments=False))

    assert without_plant(slow) == without_plant(reynolds)
    assert slow.find(f".//{D}Component[@name='Plant']").get("source") != \
        reynolds.find(f".//{D}Component[@name='Plant']").get("source")


def _component(name: str, element: str) -> etree._Element:
    return _root(name).find(f"{D}System/{D}Elements/{D}Component[@name='{element}']")


def _connections(name: str) -> set:
    return {(c.get("startElement"), c.get("startConnector"), c.get("endElement"), c.get("endConnector"))
            for c in _root(name).iterfind(f"{D}System/{D}Connections/{D}Connection")}


def test_hil_structure_keeps_the_controller_and_experiment_exactly():
    """The HIL variant swaps the rig's blocks for the proxy; the Controller element is byte for byte the same, and the
    experiment is the staircase after a 1 s lift-off lead (which nfal run drives), at the same step."""
    canonical = lambda e: etree.tostring(e, method="c14n", with_comments=False)  # noqa: E731
    assert canonical(_component("fig7_hil.ssd", "Controller")) == canonical(_component("fig7_slow.ssd", "Controller"))
    hil, slow = (_root(name).find(f"{D}DefaultExperiment") for name in ("fig7_hil.ssd", "fig7_slow.ssd"))
    assert float(hil.get("stopTime")) == pytest.approx(float(slow.get("stopTime")) + 0.9)  # lead 0.1 -> 1 s
    assert canonical(hil.find(f"{D}Annotations")) == canonical(slow.find(f"{D}Annotations"))



def test_hil_structure_wires_the_proxy():
    components = {c.get("name"): c.get("source") for c in _root("fig7_hil.ssd").iter(f"{D}Component")}
    assert components == {"Controller": "resources/Controller.fmu", "proxy": "resources/HardwareProxy.fmu"}
    assert _connections("fig7_hil.ssd") == {("Controller", "drive_voltage", "proxy", "drive_voltage"),
                                            ("proxy", "measured_height", "Controller", "measured_height")}


@pytest.mark.parametrize("name", RIG_STRUCTURES)
def test_rig_structure_is_the_loop_without_the_controller(name):
    components = {c.get("name"): c.get("source") for c in _root(name).iter(f"{D}Component")}
    assert components == {"Plant": f"resources/{RIG_STRUCTURES[name]}",
                          "ResonanceTracker": "resources/ResonanceTracker.fmu",
                          "SensorChain": "resources/SensorChain.fmu"}
    assert _connections(name) == {c for c in FIG7_CONNECTIONS if "Controller" not in (c[0], c[2])}
    plant_sets = [b.get("source") for b in _component(name, "Plant").iter(f"{D}ParameterBinding")]
    assert plant_sets == ["resources/paper_rig.ssv", "resources/rig_truth.ssv"]


def test_rig_truth_parameter_set():
    assert _parameters("rig_truth.ssv") == {
        "excess_damping_height": pytest.approx(137e-6), "excess_damping_exponent": 6.0, "near_surface": "fast",
        "initial_height": pytest.approx(5e-6), "rest_gap": pytest.approx(5e-6), "shape": "piston",
        "radial_nodes": 21, "steps_per_period": 32}


def test_paper_rig_parameter_set():
    assert _parameters("paper_rig.ssv") == pytest.approx(PAPER_RIG)


def test_table2_parameter_set():
    assert _parameters("table2.ssv") == pytest.approx(TABLE2)


def _slave_starts(*classes) -> dict:
    """Every parameter's declared start (from the models' defaults) of the FMU slave ``classes``."""
    starts = {}
    for cls in classes:
        slave = cls(instance_name="defaults")
        starts.update({name: slave.value(name) for name in slave._declarations})
    return starts


@pytest.mark.parametrize("name, slaves", [("paper_rig.ssv", (SlowPlant, Controller)),
                                          ("table2.ssv", (Controller, ResonanceTracker, SensorChain))])
def test_a_parameter_set_holds_the_fmus_own_defaults(name, slaves):
    """The shipped sets are data (SSP files cannot import a constant): each value equals the default the FMUs
    take from the models (models/rig.py, models/table2.py, models/transducer.py), so a constant changed there
    and not here fails."""
    starts = _slave_starts(*slaves)
    values = _parameters(name)
    assert set(values) <= set(starts)
    assert values == pytest.approx({key: starts[key] for key in values})


@pytest.mark.parametrize("name", [*STRUCTURES, "fig7_hil.ssd"])
def test_libcosim_loads_the_structures_as_written(name):
    """Only the note on the Controller's bindings (libcosim applies the first; run_ssp all)."""
    problems = libcosim_portability(SSP_DIR / name)
    count = 2 + len(EXTRA_BINDINGS.get(name, []))
    assert len(problems) == 1 and f"'Controller' has {count} parameter bindings" in problems[0]


def test_valid_ssp_with_other_prefixes_is_reported_as_not_portable(tmp_path):
    """Namespace-aware SSP tools accept any prefix; libcosim matches the literal ssd:/ssc:/ssv:."""
    ssd = tmp_path / "fig7_slow.ssd"
    ssd.write_text((SSP_DIR / "fig7_slow.ssd").read_text().replace("ssd:", "sd:").replace("xmlns:ssd=", "xmlns:sd="))
    rig = tmp_path / "paper_rig.ssv"
    rig.write_text((SSP_DIR / "paper_rig.ssv").read_text().replace("<ssv:", "<v:").replace("</ssv:", "</v:")
                   .replace("xmlns:ssv=", "xmlns:v="))
    (tmp_path / "table2.ssv").write_bytes((SSP_DIR / "table2.ssv").read_bytes())
    assert validate(ssd) == [] and validate(rig) == []
    problems = libcosim_portability(ssd)
    assert any(p.startswith(f"{ssd}:") and "prefix 'sd'; libcosim needs the literal 'ssd:'" in p for p in problems)
    assert any(p.startswith(f"{rig}:") and "prefix 'v'; libcosim needs the literal 'ssv:'" in p for p in problems)


# --- packing ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", STRUCTURES)
def test_packed_archive_layout(archives, name):
    with zipfile.ZipFile(archives[name]) as archive:
        names = archive.namelist()
        assert names[0] == "SystemStructure.ssd"
        assert archive.read("SystemStructure.ssd") == (SSP_DIR / name).read_bytes()
    assert sorted(names[1:]) == sorted(
        ["resources/Controller.fmu", "resources/ResonanceTracker.fmu", "resources/SensorChain.fmu",
         "resources/ReferenceGenerator.fmu", f"resources/{STRUCTURES[name]}", "resources/paper_rig.ssv",
         "resources/table2.ssv", *(f"resources/{ssv}" for ssv in EXTRA_BINDINGS[name] + REFERENCE_BINDINGS[name])])


@pytest.mark.parametrize("name", STRUCTURES)
def test_packed_archive_is_valid(archives, name):
    assert validate(archives[name]) == []


def test_packing_is_reproducible(fmu_dir, archives, tmp_path):
    again = pack(SSP_DIR / "fig7_slow.ssd", fmu_dir, tmp_path / "again.ssp")
    assert again.read_bytes() == archives["fig7_slow.ssd"].read_bytes()


def test_referenced_resources_in_document_order():
    assert referenced_resources(SSP_DIR / "fig7_slow.ssd") == {
        "fmu": ["resources/SlowPlant.fmu", "resources/Controller.fmu", "resources/ResonanceTracker.fmu",
                "resources/SensorChain.fmu", "resources/ReferenceGenerator.fmu"],
        "ssv": ["resources/paper_rig.ssv", "resources/table2.ssv"], "other": []}


def test_a_missing_fmu_is_named(fmu_dir, tmp_path):
    partial = tmp_path / "fmus"
    partial.mkdir()
    for name in ("SlowPlant", "Controller", "SensorChain", "ReferenceGenerator"):
        (partial / f"{name}.fmu").write_bytes((fmu_dir / f"{name}.fmu").read_bytes())
    with pytest.raises(MissingFmuError, match="references ResonanceTracker.fmu, not in .*holds Controller.fmu"):
        pack(SSP_DIR / "fig7_slow.ssd", partial, tmp_path / "out.ssp")
    assert not list(tmp_path.glob("*.ssp"))


def test_ssv_paths_replace_the_sets_beside_the_ssd(fmu_dir, tmp_path):
    rig = tmp_path / "paper_rig.ssv"
    rig.write_text((SSP_DIR / "paper_rig.ssv").read_text().replace('value="0.1347"', 'value="0.2"'))
    spare = tmp_path / "heavy_rig.ssv"
    spare.write_text((SSP_DIR / "paper_rig.ssv").read_text())
    archive = pack(SSP_DIR / "fig7_slow.ssd", fmu_dir, tmp_path / "out.ssp", ssv_paths=[rig, spare])
    with zipfile.ZipFile(archive) as zipped:
        assert b'value="0.2"' in zipped.read("resources/paper_rig.ssv")
        assert "resources/heavy_rig.ssv" in zipped.namelist()
        assert zipped.read("resources/table2.ssv") == (SSP_DIR / "table2.ssv").read_bytes()


def test_a_missing_parameter_set_is_named(fmu_dir, tmp_path):
    ssd = tmp_path / "fig7_slow.ssd"  # beside no .ssv
    ssd.write_bytes((SSP_DIR / "fig7_slow.ssd").read_bytes())
    with pytest.raises(StructureError, match="parameter set paper_rig.ssv"):
        pack(ssd, fmu_dir, tmp_path / "out.ssp")


def test_a_source_outside_resources_is_refused(fmu_dir, tmp_path):
    ssd = tmp_path / "bad.ssd"
    ssd.write_text((SSP_DIR / "fig7_slow.ssd").read_text().replace("resources/Controller.fmu", "../Controller.fmu"))
    with pytest.raises(StructureError, match="'../Controller.fmu' is not a relative 'resources/<file>'"):
        pack(ssd, fmu_dir, tmp_path / "out.ssp", ssv_paths=[SSP_DIR / "paper_rig.ssv", SSP_DIR / "table2.ssv"])


# --- the validator ------------------------------------------------------------------------------------

def _line_of(text: str, needle: str) -> int:
    return text[: text.index(needle)].count("\n") + 1


def test_a_schema_violation_is_reported_with_its_line(tmp_path):
    text = (SSP_DIR / "fig7_slow.ssd").read_text()
    line = _line_of(text, '<ssd:Connector name="drive_voltage" kind="output">')
    broken = tmp_path / "broken.ssd"
    broken.write_text(text.replace('<ssd:Connector name="drive_voltage" kind="output">',
                                   '<ssd:Connector name="drive_voltage" kind="outlet">', 1))
    problems = validate(broken)
    assert len(problems) == 1
    assert problems[0].startswith(f"{broken}:{line}: ") and "'outlet'" in problems[0] and "ssd:Connector" in problems[0]


def test_a_bad_parameter_value_is_reported_with_its_line(tmp_path):
    text = (SSP_DIR / "table2.ssv").read_text()
    broken = tmp_path / "table2.ssv"
    broken.write_text(text.replace('value="2e-6"', 'value="2 um"'))
    line = _line_of(text, 'value="2e-6"')
    assert validate(broken) == [f"{broken}:{line}: Element 'ssv:Real', attribute "
                                "'value': '2 um' is not a valid value of the atomic type 'xs:double'."]


def test_malformed_xml_is_reported_with_its_line(tmp_path):
    text = (SSP_DIR / "fig7_slow.ssd").read_text()
    broken = tmp_path / "broken.ssd"
    broken.write_text(text.replace("</ssd:Connections>", "</ssd:Connection>"))
    problems = validate(broken)
    assert problems == [f"{broken}:{_line_of(text, '</ssd:Connections>')}: not well-formed XML: Opening and ending "
                        f"tag mismatch: Connections line {_line_of(text, '<ssd:Connections>')} and Connection"]


def test_a_file_with_the_wrong_root_is_reported(tmp_path):
    wrong = tmp_path / "rig.ssd"
    wrong.write_bytes((SSP_DIR / "paper_rig.ssv").read_bytes())
    (problem,) = validate(wrong)
    assert "root element is ssv:ParameterSet, a .ssd file must hold ssd:SystemStructureDescription" in problem


def test_problems_inside_an_archive_name_the_member(fmu_dir, tmp_path):
    archive = pack(SSP_DIR / "fig7_slow.ssd", fmu_dir, tmp_path / "ok.ssp")
    broken = tmp_path / "broken.ssp"
    with zipfile.ZipFile(archive) as source, zipfile.ZipFile(broken, "w") as target:
        for info in source.infolist():
            if info.filename == "resources/table2.ssv":
                continue  # referenced, but gone
            data = source.read(info.filename)
            if info.filename == "resources/paper_rig.ssv":
                data = data.replace(b'name="mass"', b'nam="mass"')
            target.writestr(info, data)
    problems = validate(broken)
    assert any(p.startswith(f"{broken}!resources/paper_rig.ssv:") and "'name' is required" in p for p in problems)
    assert any(p.startswith(f"{broken}!SystemStructure.ssd:") and "'resources/table2.ssv' is not in the archive" in p
               for p in problems)


def test_an_archive_without_a_root_ssd_is_reported(tmp_path):
    archive = tmp_path / "empty.ssp"
    with zipfile.ZipFile(archive, "w") as zipped:
        zipped.writestr("resources/table2.ssv", (SSP_DIR / "table2.ssv").read_bytes())
    assert validate(archive) == [f"{archive}:0: no SystemStructure.ssd at the root of the archive"]


@pytest.mark.parametrize("name", ["x.txt", "x.fmu"])
def test_validate_refuses_other_files(tmp_path, name):
    (tmp_path / name).write_text("x")
    with pytest.raises(ValueError, match="must end in .ssp"):
        validate(tmp_path / name)


@examples(60, suppress_health_check=[HealthCheck.too_slow])
@given(position=st.integers(min_value=0), replacement=st.sampled_from(list("<>&\"'=/x 0-") + ["", "ssd:"]))
def test_any_corruption_yields_located_problems_not_exceptions(position, replacement):
    """The validator is total: any one-character edit of a valid SSD gives a list of 'file:line: message'."""
    text = (SSP_DIR / "fig7_slow.ssd").read_text()
    position %= len(text)
    edited = text[:position] + replacement + text[position + 1:]
    problems = validate_bytes(edited.encode(), "edited.ssd", ".ssd")
    for problem in problems:
        label, line, message = problem.split(":", 2)
        assert label == "edited.ssd" and int(line) >= 0 and message.strip()
