"""Reading SSP 1.0 structures and checking them against the FMUs (nfal.orchestration.ssp, .resolve)."""

from __future__ import annotations

import zipfile

import pytest

from nfal.orchestration import (CausalityError, MissingFmuError, StructureError, TypeMismatchError, UnitMismatchError,
                                UnknownConnectorError, UnknownElementError, UnsupportedFeatureError, read_ssp, resolve)
from nfal.orchestration.ssp import parse_boolean
from toy_fmus import build_toys
from toy_fmus.ssd import (bindings, component, connection, connector, pack, parameter_set, ssd, ssv_file, system,
                          write_folder)

PLANT_CONNECTORS = (connector("u", "input", "m/s"), connector("x", "output", "m"))


@pytest.fixture(scope="session")
def toys(tmp_path_factory):
    return build_toys(tmp_path_factory.getbasetemp() / "toy_fmus")


def loop_text(plant_bindings: str = "", system_bindings: str = "", plant_connectors=PLANT_CONNECTORS) -> str:
    """Integrator (Plant) and Gain (Controller) in a feedback loop."""
    return ssd(system("loop", (component("Plant", "Integrator", plant_connectors, plant_bindings),
                               component("Controller", "Gain")),
                      (connection("Plant.x", "Controller.u"), connection("Controller.y", "Plant.u")),
                      parameter_bindings=system_bindings), stop_time=1.0, step_size=0.1)


def test_folder_archive_and_bare_ssd_read_alike(tmp_path, toys):
    folder = write_folder(tmp_path / "loop", loop_text(), toys)
    archive = pack(folder, tmp_path / "loop.ssp")
    read = [read_ssp(folder), read_ssp(archive), read_ssp(folder / "SystemStructure.ssd")]
    for structure in read:
        with structure:
            assert structure.name == "toy"
            assert [c.name for c in structure.system.elements] == ["Plant", "Controller"]
            assert [(c.start, c.end) for c in structure.system.connections] == [("Plant.x", "Controller.u"),
                                                                              ("Controller.y", "Plant.u")]
            assert [c.name for c in structure.system.elements[0].connectors] == ["u", "x"]
            assert structure.default_experiment.stop_time == 1.0
            assert structure.default_experiment.step_size == 0.1
            assert structure.system.elements[0].source.is_file()
    unpacked = read[1].ssd_path.parent
    read[1].close()
    assert not unpacked.exists()


def test_connectors_are_typed(tmp_path, toys):
    with read_ssp(write_folder(tmp_path, loop_text(), toys)) as structure:
        plant = structure.system.element("Plant")
        assert plant.connector("u").kind == "input" and plant.connector("u").unit == "m/s"
        assert plant.connector("x").type == "Real" and plant.connector("x").unit == "m"


def test_ssv_file_and_inline_bindings_are_applied_later_ones_winning(tmp_path, toys):
    rig = ssv_file({"x0": ("Real", 2.5, "m"), "frozen": ("Boolean", True), "decimation": ("Integer", 3),
                    "label": ("String", "from-ssv"), "mass": ("Real", 1.0)})
    inline = parameter_set({"x0": ("Real", 4.0, "m")})
    text = loop_text(plant_bindings=bindings("resources/rig.ssv", inline))
    with read_ssp(write_folder(tmp_path, text, toys, {"resources/rig.ssv": rig})) as structure:
        plant = resolve(structure).element("Plant")
    assert plant.start_values == {"x0": 4.0, "frozen": True, "decimation": 3, "label": "from-ssv"}
    assert type(plant.start_values["decimation"]) is int


def test_names_matching_no_variable_are_ignored_and_reported(tmp_path, toys):
    text = loop_text(plant_bindings=bindings(parameter_set({"mass": ("Real", 1.0)})))
    with read_ssp(write_folder(tmp_path, text, toys)) as structure:
        system_ = resolve(structure)
    assert len(system_.unmatched_parameters) == 1 and system_.unmatched_parameters[0].endswith("mass")


def test_system_bindings_use_hierarchical_names_prefix_and_win_over_element_bindings(tmp_path, toys):
    element_level = bindings(parameter_set({"x0": ("Real", 1.0, "m")}))
    system_level = bindings(parameter_set({"Plant.x0": ("Real", 2.0, "m"), "Controller.k": ("Real", -3.0)}))
    text = loop_text(plant_bindings=element_level, system_bindings=system_level)
    with read_ssp(write_folder(tmp_path, text, toys)) as structure:
        resolved = resolve(structure)
    assert resolved.element("Plant").start_values["x0"] == 2.0
    assert resolved.element("Controller").start_values["k"] == -3.0
    prefixed = bindings(parameter_set({"k": ("Real", 2.0)})).replace("<ssd:ParameterBinding>",
                                                                      '<ssd:ParameterBinding prefix="Controller.">')
    with read_ssp(write_folder(tmp_path / "prefixed", loop_text(system_bindings=prefixed), toys)) as structure:
        assert resolve(structure).element("Controller").start_values["k"] == 2.0


def test_overrides_win_and_strings_are_parsed_by_type(tmp_path, toys):
    text = loop_text(plant_bindings=bindings(parameter_set({"x0": ("Real", 1.0, "m")})))
    overrides = {"Plant.x0": "3e-6", "Plant.frozen": "true", "Plant.decimation": 2.0, "Plant.label": "cli"}
    with read_ssp(write_folder(tmp_path, text, toys)) as structure:
        plant = resolve(structure, overrides).element("Plant")
    assert plant.start_values == {"x0": 3e-6, "frozen": True, "decimation": 2, "label": "cli"}


def test_a_system_parameter_connector_feeds_its_value_and_the_command_line_wins(tmp_path, toys):
    """A value bound to a system connector of kind parameter is the start value of what it feeds; an override of that
    variable, or of the connector, comes after the SSD's values and wins (the connector's value hid an override of
    Plant.x0 before)."""
    text = ssd(system("loop", (component("Plant", "Integrator", PLANT_CONNECTORS), component("Controller", "Gain")),
                      (connection("Plant.x", "Controller.u"), connection("Controller.y", "Plant.u"),
                       connection("start", "Plant.x0")),
                      connectors=(connector("start", "parameter", "m"),),
                      parameter_bindings=bindings(parameter_set({"start": ("Real", 2.0, "m")}))),
               stop_time=1.0, step_size=0.1)
    for overrides, expected in (({}, 2.0), ({"Plant.x0": 3.0}, 3.0), ({"start": 4.0}, 4.0)):
        with read_ssp(write_folder(tmp_path / str(expected), text, toys)) as structure:
            assert resolve(structure, overrides).element("Plant").start_values["x0"] == expected, overrides


@pytest.mark.parametrize("override, error", [
    ({"Plant.nothing": 1.0}, UnknownConnectorError),
    ({"Nobody.x0": 1.0}, UnknownElementError),
    ({"Plant.decimation": 2.5}, TypeMismatchError),
    ({"Plant.frozen": "maybe"}, TypeMismatchError),
    ({"Plant.label": 3.0}, TypeMismatchError),
    ({"Plant.x": 1.0}, CausalityError),  # an output: calculated, cannot be set
])
def test_bad_overrides_are_named(tmp_path, toys, override, error):
    with read_ssp(write_folder(tmp_path, loop_text(), toys)) as structure:
        with pytest.raises(error, match=list(override)[0].replace(".", r"\.")):
            resolve(structure, override)


def test_flattened_links_and_feedthrough(tmp_path, toys):
    with read_ssp(write_folder(tmp_path, loop_text(), toys)) as structure:
        resolved = resolve(structure)
    assert [(link.source.path, link.target.path) for link in resolved.links] == [("Plant.x", "Controller.u"),
                                                                                ("Controller.y", "Plant.u")]
    assert resolved.element("Controller").feedthrough == {"y": ("u",)}
    assert resolved.element("Plant").feedthrough == {"x": (), "steps": ()}


def test_start_and_end_do_not_give_the_direction(tmp_path, toys):
    text = loop_text().replace('startElement="Plant" startConnector="x" endElement="Controller" endConnector="u"',
                               'startElement="Controller" startConnector="u" endElement="Plant" endConnector="x"')
    with read_ssp(write_folder(tmp_path, text, toys)) as structure:
        links = resolve(structure).links
    assert ("Plant.x", "Controller.u") in [(link.source.path, link.target.path) for link in links]


def test_unknown_element_in_a_connection(tmp_path, toys):
    text = loop_text().replace('endElement="Controller" endConnector="u"', 'endElement="Controler" endConnector="u"')
    with pytest.raises(UnknownElementError, match="Controler"):
        read_ssp(write_folder(tmp_path, text, toys))


def test_missing_fmu(tmp_path, toys):
    text = loop_text().replace("resources/Gain.fmu", "resources/Missing.fmu")
    with pytest.raises(MissingFmuError, match="Controller.*Missing.fmu"):
        read_ssp(write_folder(tmp_path, text, toys))


def test_connector_not_in_the_model_description(tmp_path, toys):
    text = loop_text(plant_connectors=PLANT_CONNECTORS + (connector("speed", "output", "m/s"),))
    with read_ssp(write_folder(tmp_path, text, toys)) as structure:
        with pytest.raises(UnknownConnectorError, match="'Plant'.*'speed'"):
            resolve(structure)


def test_connection_to_a_variable_the_fmu_lacks(tmp_path, toys):
    text = loop_text().replace('endConnector="u"/><ssd:Connection startElement="Controller"',
                               'endConnector="input"/><ssd:Connection startElement="Controller"')
    with read_ssp(write_folder(tmp_path, text, toys)) as structure:
        with pytest.raises(UnknownConnectorError, match="'Controller' has no variable 'input'"):
            resolve(structure)


def test_connector_kind_against_causality(tmp_path, toys):
    text = loop_text(plant_connectors=(connector("u", "output", "m/s"), connector("x", "output", "m")))
    with read_ssp(write_folder(tmp_path, text, toys)) as structure:
        with pytest.raises(CausalityError, match="'Plant'.*'u'.*output.*input"):
            resolve(structure)


def test_output_to_output_is_a_causality_error(tmp_path, toys):
    text = loop_text().replace('endElement="Controller" endConnector="u"', 'endElement="Controller" endConnector="y"')
    with read_ssp(write_folder(tmp_path, text, toys)) as structure:
        with pytest.raises(CausalityError, match="Plant.x.*Controller.y"):
            resolve(structure)


def test_unit_mismatch_between_connector_and_fmu(tmp_path, toys):
    text = loop_text(plant_connectors=(connector("u", "input", "m/s"), connector("x", "output", "mm")))
    with read_ssp(write_folder(tmp_path, text, toys)) as structure:
        with pytest.raises(UnitMismatchError, match="'Plant'.*'x'.*'mm'.*'m'"):
            resolve(structure)


def test_unit_mismatch_between_the_two_ends(tmp_path, toys):
    text = ssd(system("chain", (component("A", "Integrator"), component("B", "Integrator")),
                      (connection("A.x", "B.u"),)))
    with read_ssp(write_folder(tmp_path, text, toys)) as structure:
        with pytest.raises(UnitMismatchError, match=r"A\.x.*'m'.*B\.u.*'m/s'"):
            resolve(structure)


def test_differently_named_units_with_one_definition_are_compatible(tmp_path, toys):
    units = ('<ssc:Unit name="metre"><ssc:BaseUnit m="1"/></ssc:Unit>'
             '<ssc:Unit name="m"><ssc:BaseUnit m="1"/></ssc:Unit>')
    text = ssd(system("loop", (component("Plant", "Integrator", (connector("x", "output", "metre"),)),
                               component("Controller", "Gain")),
                      (connection("Plant.x", "Controller.u"),)), units=units)
    with read_ssp(write_folder(tmp_path, text, toys)) as structure:
        resolve(structure)  # no error: metre and m are the same unit


def test_ssv_value_in_the_wrong_unit(tmp_path, toys):
    text = loop_text(plant_bindings=bindings("resources/bad.ssv"))
    files = {"resources/bad.ssv": ssv_file({"x0": ("Real", 1.0, "s")})}
    with read_ssp(write_folder(tmp_path, text, toys, files)) as structure:
        with pytest.raises(UnitMismatchError, match="bad.ssv.*x0"):
            resolve(structure)


def test_ssv_value_of_the_wrong_type(tmp_path, toys):
    text = loop_text(plant_bindings=bindings(parameter_set({"frozen": ("Real", 1.0)})))
    with read_ssp(write_folder(tmp_path, text, toys)) as structure:
        with pytest.raises(TypeMismatchError, match="frozen"):
            resolve(structure)


def test_system_input_connector_drives_element_inputs(tmp_path, toys):
    text = ssd(system("open", (component("Controller", "Gain"),), (connection("reference", "Controller.u"),),
                      connectors=(connector("reference", "input", "m"),),
                      parameter_bindings=bindings(parameter_set({"reference": ("Real", 0.5, "m")}))))
    with read_ssp(write_folder(tmp_path, text, toys)) as structure:
        resolved = resolve(structure)
    reference = resolved.system_inputs["reference"]
    assert [t.path for t in reference.targets] == ["Controller.u"] and reference.value == 0.5
    assert reference.unit == "m"


def test_nested_systems_are_flattened_through_their_connectors(tmp_path, toys):
    inner = system("Inner", (component("Controller", "Gain"),),
                   (connection("e", "Controller.u"), connection("Controller.y", "command")),
                   connectors=(connector("e", "input"), connector("command", "output")))
    text = ssd(system("outer", (component("Plant", "Integrator"), inner),
                      (connection("Plant.x", "Inner.e"), connection("Inner.command", "Plant.u")),
                      parameter_bindings=bindings(parameter_set({"Inner.Controller.k": ("Real", -2.0)}))))
    with read_ssp(write_folder(tmp_path, text, toys)) as structure:
        resolved = resolve(structure)
    assert [e.name for e in resolved.elements] == ["Plant", "Inner.Controller"]
    assert {(link.source.path, link.target.path) for link in resolved.links} == {("Plant.x", "Inner.Controller.u"),
                                                                               ("Inner.Controller.y", "Plant.u")}
    assert resolved.element("Inner.Controller").start_values == {"k": -2.0}


def test_referenced_ssd_is_read_as_a_nested_system(tmp_path, toys):
    inner_text = ssd(system("sub", (component("Controller", "Gain"),),
                            (connection("e", "Controller.u"), connection("Controller.y", "command")),
                            connectors=(connector("e", "input"), connector("command", "output"))))
    write_folder(tmp_path, inner_text, toys)
    (tmp_path / "SystemStructure.ssd").rename(tmp_path / "controller.ssd")
    outer = ssd(system("outer", (component("Plant", "Integrator"),
                                 '<ssd:Component name="Ctl" source="controller.ssd" '
                                 'type="application/x-ssp-definition">'
                                 '<ssd:Connectors><ssd:Connector name="e" kind="input"/>'
                                 '<ssd:Connector name="command" kind="output"/></ssd:Connectors></ssd:Component>'),
                       (connection("Plant.x", "Ctl.e"), connection("Ctl.command", "Plant.u"))))
    (tmp_path / "SystemStructure.ssd").write_text(outer)
    with read_ssp(tmp_path) as structure:
        resolved = resolve(structure)
    assert [e.name for e in resolved.elements] == ["Plant", "Ctl.Controller"]


def test_an_archive_with_windows_separators_unpacks_as_its_folder(tmp_path, toys):
    """Windows PowerShell 5's Compress-Archive names entries resources\\Gain.fmu: the FMU was "not found"."""
    folder = write_folder(tmp_path / "loop", loop_text(), toys)
    archive = tmp_path / "windows.ssp"
    with zipfile.ZipFile(archive, "w") as zip_file:
        for path in sorted(folder.rglob("*")):
            if path.is_file():
                zip_file.write(path, "\\".join(path.relative_to(folder).parts))
    assert "resources\\Gain.fmu" in zipfile.ZipFile(archive).namelist()
    with read_ssp(archive) as structure:
        assert structure.system.element("Controller").source.is_file()


def test_an_archives_errors_name_the_archive_not_its_deleted_unpacked_folder(tmp_path, toys):
    folder = write_folder(tmp_path / "loop", loop_text(), toys)
    (folder / "resources" / "Gain.fmu").unlink()
    archive = pack(folder, tmp_path / "loop.ssp")
    with pytest.raises(MissingFmuError) as raised:
        read_ssp(archive)
    assert f"looked for {archive}: resources/Gain.fmu" in str(raised.value) and "nfal-ssp-" not in str(raised.value)


def test_another_ssp_version_is_said_once_naming_the_archive(tmp_path, toys, caplog):
    """An SSP 2.0 archive: the warning came twice (nfal run reads a structure twice) and named the unpacked SSD, a
    temporary folder gone by then."""
    text = loop_text().replace('name="toy" version="1.0"', 'name="toy" version="2.0"')
    folder = write_folder(tmp_path / "loop", text, toys)
    archive = pack(folder, tmp_path / "two.ssp")
    for _ in range(2):
        read_ssp(archive).close()
    warned = [r.getMessage() for r in caplog.records if "SSP version" in r.getMessage()]
    assert warned == [f"{archive}: SystemStructure.ssd: SSP version '2.0'; reading it as SSP 1.0"]


def test_a_text_longer_than_the_xml_reader_takes_is_named_so(tmp_path, toys):
    """A 12 MB annotation: libxml2's limit (kept: it stops XML bombs) read as "not well-formed XML ...
    XML_PARSE_HUGE"."""
    annotation = f'<ssd:Annotations><ssc:Annotation type="x">{"a" * 12_000_000}</ssc:Annotation></ssd:Annotations>'
    text = loop_text().replace("</ssd:SystemStructureDescription>", annotation + "</ssd:SystemStructureDescription>")
    with pytest.raises(StructureError, match="longer than the 10 MB the XML reader takes"):
        read_ssp(write_folder(tmp_path, text, toys))


def test_parameter_values_that_are_not_a_file_are_named_so(tmp_path, toys):
    text = loop_text(plant_bindings=bindings("/dev/null"))
    with pytest.raises(StructureError, match="not a regular file"):
        read_ssp(write_folder(tmp_path, text, toys))


def test_a_relative_file_uri_is_relative_to_the_ssd_not_the_working_folder(tmp_path, toys, monkeypatch):
    """``file:resources/Gain.fmu`` (no slash after the colon) is a relative reference: it was looked up from wherever
    the command ran, which could load another FMU of that name."""
    text = loop_text().replace('source="resources/Gain.fmu"', 'source="file:resources/Gain.fmu"')
    folder = write_folder(tmp_path / "loop", text, toys)
    (tmp_path / "elsewhere" / "resources").mkdir(parents=True)
    monkeypatch.chdir(tmp_path / "elsewhere")
    with read_ssp(folder) as structure:
        assert structure.system.element("Controller").source == folder / "resources" / "Gain.fmu"


@pytest.mark.parametrize("change, feature", [
    (('<ssd:Connection startElement="Plant" startConnector="x" endElement="Controller" endConnector="u"/>',
      '<ssd:Connection startElement="Plant" startConnector="x" endElement="Controller" endConnector="u">'
      '<ssc:BooleanMappingTransformation/></ssd:Connection>'), "BooleanMappingTransformation"),
    (('source="resources/Gain.fmu"', 'source="resources/Gain.fmu" implementation="ModelExchange"'), "ModelExchange"),
    (('source="resources/Gain.fmu"', 'source="http://example.com/Gain.fmu"'), "file: URIs"),
])
def test_unsupported_features_are_named(tmp_path, toys, change, feature):
    text = loop_text().replace(*change)
    with pytest.raises(UnsupportedFeatureError, match=feature):
        read_ssp(write_folder(tmp_path, text, toys))


@pytest.mark.parametrize("text, message", [
    ("<notssd/>", "not an SSP 1.0 system structure"),
    ("<ssd:Broken", "not well-formed"),
])
def test_not_an_ssd(tmp_path, text, message):
    (tmp_path / "SystemStructure.ssd").write_text(text)
    with pytest.raises(StructureError, match=message):
        read_ssp(tmp_path)


LINK = '<ssd:Connection startElement="Plant" startConnector="x" endElement="Controller" endConnector="u"/>'
TRANSFORM = '<ssc:LinearTransformation factor="2"/>'


@pytest.mark.parametrize("change, message", [
    ((LINK, LINK.replace("/>", f">{TRANSFORM}{TRANSFORM}</ssd:Connection>")), "a second LinearTransformation"),
    (('<ssd:Component name="Plant" source="resources/Integrator.fmu">',
      '<ssd:Component name="Plant" source="resources/Integrator.fmu">' + bindings(parameter_set(
          {"x0": ("Real", 1.0), "x1": ("Real", 2.0)}).replace('"x1"', '"x0"'))), "given twice"),
    (('<ssd:Component name="Plant" source="resources/Integrator.fmu">',
      '<ssd:Component name="Plant" source="resources/Integrator.fmu">' + bindings(parameter_set(
          {"x0": ("Real", 1.0)})).replace("<ssd:ParameterBinding>", '<ssd:ParameterBinding source="rig.ssv">')),
     "not both"),
    (('<ssd:Component name="Controller" source="resources/Gain.fmu"></ssd:Component>',
      '<ssd:Component name="Controller" source="resources/Gain.fmu"/><ssd:System name="Sub"><ssd:Elements>'
      '<ssd:Component name="x" source="resources/Gain.fmu"/></ssd:Elements></ssd:System>'
      '<ssd:Component name="Sub.x" source="resources/Gain.fmu"/>'), "more than one element named 'Sub.x'"),
])
def test_what_the_ssd_says_twice_is_refused_not_half_applied(tmp_path, toys, change, message):
    """Two transformations on a connection, a name twice in a parameter set, a binding's source and inline values,
    two elements with one hierarchical name: each used to keep one of the two silently."""
    text = loop_text()
    assert change[0] in text
    with pytest.raises(StructureError, match=message):
        read_ssp(write_folder(tmp_path, text.replace(*change), toys, {"rig.ssv": ssv_file({"x0": ("Real", 2.0)})}))


@pytest.mark.parametrize("name, hint", [("X0", "did you mean 'x0'"), ("Plant.x0", "without the element's name")])
def test_a_name_an_elements_binding_misses_by_case_or_by_prefix_is_a_typo(tmp_path, toys, name, hint):
    text = loop_text(plant_bindings=bindings(parameter_set({name: ("Real", 1.0)})))
    with read_ssp(write_folder(tmp_path, text, toys)) as structure:
        with pytest.raises(UnknownConnectorError, match=hint):
            resolve(structure)


def test_a_second_source_for_one_input_is_an_error(tmp_path, toys):
    text = ssd(system("two", (component("A", "Gain"), component("B", "Gain"), component("C", "Gain")),
                      (connection("A.y", "C.u"), connection("B.y", "C.u"))))
    with read_ssp(write_folder(tmp_path, text, toys)) as structure:
        with pytest.raises(CausalityError, match="C.u already has a source"):
            resolve(structure)


@pytest.mark.parametrize("text, value", [("true", True), (" TRUE ", True), ("1", True), ("False", False), ("0", False),
                                         ("maybe", None), ("", None), ("2", None), ("yes", None)])
def test_one_reading_of_a_boolean_written_as_text(text, value):
    assert parse_boolean(text) is value
