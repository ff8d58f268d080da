"""The FMI 3.0 face of an nfal slave: :class:`Fmi3Adapter`, so one slave definition serves both FMI versions.

Every slave (``fmus/slow_plant.py`` ...) is written once, against :class:`~nfal.fmus.base.NfalSlave`
(pythonfmu, FMI 2.0). ``nfal build --fmi 3`` packs it with pythonfmu3's FMI 3.0 wrapper and a generated
script (:func:`fmi3_script`) that declares ``class SlowPlant(Fmi3Adapter, _Slave, Fmi3SlaveBase)``:
the slave's declarations, numerics, guards and FMU state stay as they are; this mixin answers the
calls that differ in FMI 3.0 and writes an FMI 3.0 modelDescription.xml:

* the wrapper's ``get_float64``/``set_float64``/``get_int32``/``set_int32`` are the slave's
  ``get_real``/``set_real``/``get_integer``/``set_integer`` (Booleans and Strings keep their names);
* ``<Float64>``, ``<Int32>``, ``<Boolean>``, ``<String>`` variables with the same value references,
  units (``<UnitDefinitions>``), causality, variability and start values, plus the ``time`` variable
  (causality ``independent``) that FMI 3.0 requires, after the slave's own;
* ``<ModelStructure>``: an ``<Output>`` per output with the same ``dependencies`` (value references
  in FMI 3.0) and an ``<InitialUnknown>`` per output.

pythonfmu3 (0.3.4) calls the same Python entry points (``setup_experiment(start_time)``,
``enter/exit_initialization_mode``, ``do_step``, ``_get_fmu_state`` ...). The FMU's binary is our
patched build of pythonfmu3's runtime (``fmus/runtime3/``, :mod:`nfal.fmus.export_runtime`): as in
FMI 2.0, a failed call is one logged line ``"<instance>: <reason> (in <call>)"`` with fmi3Error,
and the instance stays usable.
"""

from __future__ import annotations

from xml.etree.ElementTree import Element, SubElement

from pythonfmu.enums import Fmi2Causality, Fmi2Variability
from pythonfmu.variables import Boolean, Integer, Real, String
from pythonfmu3 import __version__ as PYTHONFMU3_VERSION

#: The FMI 3.0 element of each pythonfmu variable class.
FMI3_TYPES = {Real: "Float64", Integer: "Int32", Boolean: "Boolean", String: "String"}
#: modelDescription attributes FMI 3.0 keeps from FMI 2.0.
ROOT_ATTRIBUTES = ("modelName", "description", "author", "version", "copyright", "license", "generationTool",
                   "generationDateAndTime")
#: CoSimulation attributes FMI 3.0 keeps (FMI 2.0 name -> FMI 3.0 name).
COSIMULATION_ATTRIBUTES = {"modelIdentifier": "modelIdentifier", "needsExecutionTool": "needsExecutionTool",
                           "canBeInstantiatedOnlyOncePerProcess": "canBeInstantiatedOnlyOncePerProcess",
                           "canHandleVariableCommunicationStepSize": "canHandleVariableCommunicationStepSize",
                           "canGetAndSetFMUstate": "canGetAndSetFMUState",
                           "canSerializeFMUstate": "canSerializeFMUState"}
#: The independent variable FMI 3.0 requires (its value reference follows the slave's variables).
TIME = "time"


class Fmi3Adapter:
    """Mixin before an :class:`~nfal.fmus.base.NfalSlave` subclass (and before pythonfmu3's
    ``Fmi3SlaveBase``, which only marks the class for pythonfmu3's builder and loader)."""

    def get_float64(self, vrs):
        time_vr = len(self.vars)
        if time_vr in vrs:  # the independent variable is not one of the slave's
            return [self.time if vr == time_vr else self.get_real([vr])[0] for vr in vrs]
        return self.get_real(vrs)

    def set_float64(self, vrs, values) -> None:
        self.set_real(vrs, values)

    def get_int32(self, vrs):
        return self.get_integer(vrs)

    def set_int32(self, vrs, values) -> None:
        self.set_integer(vrs, values)

    def to_xml(self, model_options: dict | None = None) -> Element:
        """The FMI 3.0 modelDescription of the slave (see the module docstring)."""
        fmi2 = super().to_xml(model_options)  # NfalSlave's FMI 2.0 description: options, units, structure
        attributes = {k: v for k, v in fmi2.attrib.items() if k in ROOT_ATTRIBUTES}
        attributes["generationTool"] = (f"{fmi2.get('generationTool')} and PythonFMU3 {PYTHONFMU3_VERSION} "
                                        "(nfal.fmus.fmi3)")
        root = Element("fmiModelDescription", {"fmiVersion": "3.0", **attributes,
                                               "instantiationToken": fmi2.get("guid")})
        cosimulation = {COSIMULATION_ATTRIBUTES[k]: v for k, v in fmi2.find("CoSimulation").attrib.items()
                        if k in COSIMULATION_ATTRIBUTES}
        SubElement(root, "CoSimulation", cosimulation)
        root.append(_with_seconds(fmi2.find("UnitDefinitions")))
        for section in ("LogCategories", "DefaultExperiment"):
            node = fmi2.find(section)
            if node is not None:
                root.append(node)
        for category in root.iter("Category"):
            category.set("description", category.get("description", "").replace("fmi2", "fmi3"))
        starts = {node.get("name"): child.get("start") for node in fmi2.find("ModelVariables")
                  for child in node if child.get("start") is not None}
        self._fmi3_variables(SubElement(root, "ModelVariables"), starts)
        self._fmi3_structure(SubElement(root, "ModelStructure"))
        return root

    def _fmi3_variables(self, parent: Element, starts: dict[str, str]) -> None:
        """The slave's variables as FMI 3.0 elements; ``starts``: the start values as FMI 2.0 wrote them."""
        for declared in self._declarations.values():
            variable = declared.variable
            kind = FMI3_TYPES[type(variable)]
            attributes = {"name": variable.name, "valueReference": str(variable.value_reference),
                          "causality": variable.causality.name, "variability": variable.variability.name}
            if variable.description:
                attributes["description"] = variable.description
            if declared.unit is not None:
                attributes["unit"] = declared.unit
            start = starts.get(variable.name)
            if variable.causality == Fmi2Causality.output:
                attributes["initial"] = "calculated"
            elif kind != "String":
                attributes["start"] = start
            node = SubElement(parent, kind, attributes)
            if kind == "String" and start is not None:
                SubElement(node, "Start", {"value": start})
        SubElement(parent, "Float64", {"name": TIME, "valueReference": str(len(self.vars)), "causality": "independent",
                                       "variability": Fmi2Variability.continuous.name, "unit": "s",
                                       "description": "simulation time"})

    def _fmi3_structure(self, parent: Element) -> None:
        declared = self._declarations
        outputs = [d for d in declared.values() if d.variable.causality == Fmi2Causality.output]
        for d in outputs:
            attributes = {"valueReference": str(d.variable.value_reference)}
            if d.depends_on:
                attributes["dependencies"] = " ".join(str(declared[s].variable.value_reference) for s in d.depends_on)
                attributes["dependenciesKind"] = " ".join("dependent" for _ in d.depends_on)
            SubElement(parent, "Output", attributes)
        for d in outputs:
            SubElement(parent, "InitialUnknown", {"valueReference": str(d.variable.value_reference)})


def _with_seconds(definitions: Element | None) -> Element:
    """The unit definitions, with the second (the unit of ``time``) added if missing."""
    definitions = definitions if definitions is not None else Element("UnitDefinitions")
    if not any(unit.get("name") == "s" for unit in definitions):
        SubElement(SubElement(definitions, "Unit", name="s"), "BaseUnit", s="1")
    return definitions


def fmi3_script(model: str, fmi2_module: str, docstring: str) -> str:
    """The pythonfmu3 slave script of ``model``: its FMI 2.0 slave class (from the bundle loader module
    ``fmi2_module``) with :class:`Fmi3Adapter` before it, both from the FMU's own nfal. pythonfmu3 finds the
    class by the literal ``class X(... Fmi3Slave...)``."""
    return (f'"""{model}, FMI 3.0 (nfal build --fmi 3): {docstring}"""\n\n'
            "from pythonfmu3 import Fmi3SlaveBase\n"
            "import sys\n\n"
            f"sys.modules.pop({fmi2_module!r}, None)  # this FMU's own, not a same-named one loaded before\n"
            f"import {fmi2_module} as _bundle  # noqa: E402\n\n"
            "# the adapter from this FMU's own nfal, as the slave (fmus/bundle_loader.py)\n"
            'Fmi3Adapter = _bundle.load_slave(_bundle.__file__, "nfal.fmus.fmi3", "Fmi3Adapter")\n'
            f"_Slave = _bundle.{model}\n\n\n"
            f"class {model}(Fmi3Adapter, _Slave, Fmi3SlaveBase):\n"
            f'    __doc__ = _Slave.__doc__\n')
