"""Shared by the toy FMUs: declare units and output dependencies, which pythonfmu 0.7 does not write."""

from xml.etree.ElementTree import Element, SubElement


def declare_units_and_dependencies(root: Element, units: dict, dependencies: dict) -> Element:
    """Add ``unit`` attributes, ``UnitDefinitions`` and output ``dependencies`` to pythonfmu's XML."""
    variables = root.find("ModelVariables")
    index = {sv.get("name"): i + 1 for i, sv in enumerate(variables)}
    for sv in variables:
        if sv.get("name") in units:
            sv.find("Real").set("unit", units[sv.get("name")])
    definitions = Element("UnitDefinitions")
    for unit in sorted(set(units.values())):
        SubElement(definitions, "Unit", name=unit)
    position = list(root).index(root.find("CoSimulation")) + 1
    root.insert(position, definitions)
    for unknown in root.find("ModelStructure").find("Outputs"):
        name = variables[int(unknown.get("index")) - 1].get("name")
        inputs = dependencies.get(name, [])
        unknown.set("dependencies", " ".join(str(index[i]) for i in inputs))
        if inputs:
            unknown.set("dependenciesKind", " ".join("dependent" for _ in inputs))
    return root
