"""Toy FMU for the orchestrator's tests: a gain y = k u with direct feedthrough (declared).

The output is computed when it is read, from the current input (docs/cosimulation.md), and
ModelStructure declares y's dependency on u; ``do_step`` has nothing to commit.
"""

from _toy_xml import declare_units_and_dependencies
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real

UNITS = {"k": "1/s"}  # u and y: no unit, so gains can be chained in any loop
DEPENDENCIES = {"y": ["u"]}


class Gain(Fmi2Slave):
    author = "nfal tests"
    description = "y = k u, direct feedthrough"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.u = 0.0
        self.k = 1.0
        self.register_variable(Real("u", causality=Fmi2Causality.input, variability=Fmi2Variability.continuous))
        self.register_variable(Real("y", causality=Fmi2Causality.output, variability=Fmi2Variability.continuous,
                                    getter=lambda: self.k * self.u))
        self.register_variable(Real("k", causality=Fmi2Causality.parameter, variability=Fmi2Variability.tunable))

    def do_step(self, current_time, step_size):
        return True

    def to_xml(self, model_options=dict()):
        return declare_units_and_dependencies(super().to_xml(model_options), UNITS, DEPENDENCIES)

