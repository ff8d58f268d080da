"""Toy FMU for the orchestrator's tests: an integrator x' = u (no direct feedthrough).

``do_step`` integrates the held input exactly: x(t + dt) = x(t) + u dt (every ``decimation``-th
step only, unless ``frozen``). It raises (-> fmi2Error/Fatal with a logged reason) when a step would
end after ``fail_time``, so tests can check what the master keeps when a slave fails mid-run.
Units and the (empty) output dependencies are declared by ``to_xml``, which pythonfmu 0.7 does not do.
"""

from _toy_xml import declare_units_and_dependencies
from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real, String

UNITS = {"u": "m/s", "x": "m", "x0": "m", "fail_time": "s"}
DEPENDENCIES = {"x": [], "steps": []}


class Integrator(Fmi2Slave):
    author = "nfal tests"
    description = "x' = u, exact for a held input"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.u = 0.0
        self.x = 0.0
        self.x0 = 0.0
        self.fail_time = 1e300
        self.frozen = False
        self.decimation = 1
        self.label = "integrator"
        self.steps = 0
        self.register_variable(Real("u", causality=Fmi2Causality.input, variability=Fmi2Variability.continuous))
        self.register_variable(Real("x", causality=Fmi2Causality.output, variability=Fmi2Variability.continuous))
        self.register_variable(Integer("steps", causality=Fmi2Causality.output, variability=Fmi2Variability.discrete))
        self.register_variable(Real("x0", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed))
        self.register_variable(Real("fail_time", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed))
        self.register_variable(Boolean("frozen", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed))
        self.register_variable(Integer("decimation", causality=Fmi2Causality.parameter,
                                       variability=Fmi2Variability.fixed))
        self.register_variable(String("label", causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed))

    def enter_initialization_mode(self):
        self.x = self.x0

    def exit_initialization_mode(self):
        if self.decimation < 1:
            raise ValueError(f"decimation = {self.decimation} must be >= 1")
        self.x = self.x0

    def do_step(self, current_time, step_size):
        if current_time + step_size > self.fail_time * (1 + 1e-12):
            raise RuntimeError(f"{self.label} fails by design at t = {current_time + step_size:g} s")
        if not self.frozen and self.steps % self.decimation == 0:
            self.x += self.u * step_size
        self.steps += 1
        return True

    def to_xml(self, model_options=dict()):
        return declare_units_and_dependencies(super().to_xml(model_options), UNITS, DEPENDENCIES)

