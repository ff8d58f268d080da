"""fmus/base.py and fmus/build.py: declarations, modelDescription.xml, errors, FMU state, self-contained build.

A small test slave (``Scale``) exercises the base class, first as a Python object, then built with
:func:`nfal.fmus.build.build_fmus` and run through fmpy (``Instance``, tests/helpers/fmu_instance.py).
"""

from __future__ import annotations

import gc
import json
import math
import subprocess
import sys
import textwrap
from pathlib import Path

import fmpy
import pytest
from fmpy import extract
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu
from helpers.fmu_instance import FMI_ERROR, Instance, build_and_extract, runtime_slave

from nfal.errors import InvalidParameterError
from nfal.fmus import build
from nfal.fmus.base import UNITS, VALUE_CACHE_ENV, NfalSlave, SampleClock


# --- the test slave -----------------------------------------------------------------------------------
SCALE_SCRIPT = '''
"""Test slave: y = k u (feedthrough), total = running sum of k u dt (state)."""
from nfal.errors import InvalidParameterError, require_positive
from nfal.fmus.base import NfalSlave


class Scale(NfalSlave):
    description = "test slave"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.add_parameter("k", 2.0, unit="1", description="gain")
        self.add_parameter("label", "scale", description="a string parameter")
        self.add_parameter("enabled", True, description="a Boolean parameter")
        self.add_parameter("repeat", 1, description="an Integer parameter")
        self.add_parameter("offset", 0.0, unit="m", description="a tunable parameter", tunable=True)
        self.add_input("u", 0.0, unit="m", description="input")
        self.add_output("y", unit="m", description="k u + offset", depends_on=("u",),
                        getter=lambda: self.k * self.u + self.offset)
        self.add_output("total", unit="m", description="sum of k u dt / 1 s")
        self.add_output("positive", kind=bool, description="total > 0")
        self.steps = 0

    def setup(self):
        require_positive("k", self.k)
        if self.label == "reject":
            raise InvalidParameterError("label", self.label, "anything but 'reject'")

    def step(self, current_time, step_size):
        if self.u > 1.0:
            raise InvalidParameterError("u", self.u, "<= 1 m")
        self.total += self.k * self.u * step_size
        self.positive = self.total > 0
        self.steps += self.repeat

    def terminate(self):
        self.positive = False  # an output that changes as the slave terminates (as the HardwareProxy's link_ok)

    def get_internal_state(self):
        return {"steps": self.steps}

    def set_internal_state(self, state):
        self.steps = state["steps"]
'''


@pytest.fixture(scope="module")
def scale_script(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("scripts") / "scale.py"
    path.write_text(SCALE_SCRIPT, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def scale_class(scale_script):
    namespace: dict = {}
    exec(compile(scale_script.read_text(), str(scale_script), "exec"), namespace)
    return namespace["Scale"]


@pytest.fixture(scope="module")
def scale_fmu(tmp_path_factory, scale_script):
    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(build.FMU_SCRIPTS, "Scale", str(scale_script))
        yield build_and_extract(tmp_path_factory, "Scale")["Scale"]


@pytest.fixture()
def scale(scale_fmu):
    instance = Instance(*scale_fmu)
    yield instance
    instance.free()


# --- as a Python object -------------------------------------------------------------------------------
def test_declared_values_live_in_attributes(scale_class):
    slave = scale_class(instance_name="s")
    assert (slave.k, slave.label, slave.enabled, slave.repeat, slave.u) == (2.0, "scale", True, 1, 0.0)
    names = {v.name: v for v in slave.vars.values()}
    slave.set_real([names["u"].value_reference], [0.25])
    assert slave.get_real([names["y"].value_reference]) == [0.5]  # computed on read from the input


def test_real_inputs_must_be_finite(scale_class):
    slave = scale_class(instance_name="s")
    vr = {v.name: v.value_reference for v in slave.vars.values()}
    with pytest.raises(InvalidParameterError, match="u = nan"):
        slave.set_real([vr["u"]], [math.nan])
    assert slave.log_queue and slave.log_queue[-1].msg.endswith("(in setReal)")


@pytest.mark.parametrize("start", [math.nan, math.inf])
def test_a_start_time_must_be_finite(scale_class, start):
    """Every sample clock is anchored at it (an FMI 3.0 host's reaches the slave too): NaN sampled never."""
    slave = scale_class(instance_name="s")
    with pytest.raises(InvalidParameterError, match="start time"):
        slave.setup_experiment(start, 1.0)
    assert slave.log_queue and "setup_experiment" in slave.log_queue[-1].msg
    slave.setup_experiment(0.5, math.nan)  # a stop time only plans: a strange one is taken as given
    assert slave.start_time == 0.5


def test_a_value_reference_of_another_type_is_refused_saying_so_once(scale_class):
    """The exchange's fast path answers only what it can; the checked path raises and logs, once."""
    slave = scale_class(instance_name="s")
    vr = {v.name: v.value_reference for v in slave.vars.values()}
    with pytest.raises(TypeError, match=f"valueReference={vr['repeat']} is not of type Real"):
        slave.get_real([vr["u"], vr["repeat"]])
    with pytest.raises(TypeError, match=f"valueReference={vr['u']} is not of type Integer"):
        slave.set_integer([vr["repeat"], vr["u"]], [2, 1])
    assert [m.msg.rsplit("(in ", 1)[-1] for m in slave.log_queue] == ["getReal)", "setInteger)"]
    assert slave.get_integer([vr["repeat"]]) == [2] and slave.get_boolean([vr["enabled"]]) == [True]


def test_parameters_are_checked_when_initialisation_ends(scale_class):
    slave = scale_class(instance_name="s")
    vr = {v.name: v.value_reference for v in slave.vars.values()}
    slave.set_real([vr["k"]], [-1.0])  # accepted when set
    with pytest.raises(InvalidParameterError, match="k = -1.0"):
        slave.exit_initialization_mode()


def test_fixed_parameters_cannot_change_after_initialisation(scale_class):
    slave = scale_class(instance_name="s")
    vr = {v.name: v.value_reference for v in slave.vars.values()}
    slave.setup_experiment(0.0)
    slave.exit_initialization_mode()
    slave.set_real([vr["offset"]], [1e-3])  # tunable
    assert slave.offset == 1e-3
    with pytest.raises(InvalidParameterError, match="fixed parameter"):
        slave.set_real([vr["k"]], [3.0])


def test_outputs_cannot_be_set(scale_class):
    slave = scale_class(instance_name="s")
    vr = {v.name: v.value_reference for v in slave.vars.values()}
    with pytest.raises(InvalidParameterError, match="it is an output"):
        slave.set_real([vr["total"]], [1.0])


def test_declaration_errors(scale_class):
    slave = scale_class(instance_name="s")
    with pytest.raises(InvalidParameterError, match="unit"):
        slave.add_parameter("bad", 1.0, unit="furlong")
    with pytest.raises(InvalidParameterError, match="depends_on"):
        slave.add_output("z", depends_on=("k",), getter=lambda: 0.0)  # k is a parameter, not an input
    with pytest.raises(InvalidParameterError, match="not declared before"):
        slave.add_input("u", 0.0)
    with pytest.raises(InvalidParameterError, match="non-Real"):
        slave.add_parameter("flag", True, unit="m")


def test_model_description_has_units_dependencies_and_initial_unknowns(scale_class):
    root = scale_class(instance_name="s").to_xml()
    units = {u.get("name"): u.find("BaseUnit").attrib for u in root.find("UnitDefinitions")}
    assert units == {"1": {}, "m": {"m": "1"}}
    assert [child.tag for child in root][:2] == ["CoSimulation", "UnitDefinitions"]
    variables = root.find("ModelVariables").findall("ScalarVariable")
    index = {v.get("name"): i + 1 for i, v in enumerate(variables)}
    reals = {v.get("name"): v.find("Real") for v in variables if v.find("Real") is not None}
    assert all(real.get("unit") for real in reals.values())
    outputs = {int(u.get("index")): u.attrib for u in root.find("ModelStructure/Outputs")}
    assert outputs[index["y"]]["dependencies"] == str(index["u"])
    assert outputs[index["y"]]["dependenciesKind"] == "dependent"
    assert outputs[index["total"]]["dependencies"] == "" and outputs[index["positive"]]["dependencies"] == ""
    initial = [int(u.get("index")) for u in root.find("ModelStructure/InitialUnknowns")]
    assert initial == sorted(outputs)
    assert root.find("CoSimulation").get("canGetAndSetFMUstate") == "true"


def test_every_unit_has_si_base_exponents():
    allowed = {"kg", "m", "s", "A", "K", "mol", "cd", "rad"}
    assert all(set(exponents) <= allowed for exponents in UNITS.values())


@pytest.mark.parametrize("time_s, expected", [(0.0, 0), (5e-4, 1), (0.1 + 5e-4, 201), (3.7, 7400), (2.5e-4, None),
                                              (5e-4 * (1 + 1e-12), 1), (-5e-4, None)])
def test_sample_clock_instants(time_s, expected):
    assert SampleClock(5e-4).index(time_s) == expected


@pytest.mark.parametrize("step_s, accepted", [(5e-4, True), (2.5e-4, True), (1e-4, True), (5e-4 / 3, True),
                                             (1e-3, False), (3e-4, False), (4e-4, False), (6e-4, False)])
def test_sample_clock_accepts_only_steps_that_divide_the_period(step_s, accepted):
    clock = SampleClock(5e-4)
    if accepted:
        clock.check_step(step_s)
    else:
        with pytest.raises(InvalidParameterError, match="sample period 0.0005 s divided by a whole number"):
            clock.check_step(step_s)


def test_the_base_is_abstract():
    with pytest.raises(TypeError):
        NfalSlave(instance_name="x")


# --- built and run with fmpy --------------------------------------------------------------------------
def test_built_fmu_validates(scale_fmu):
    assert validate_fmu(str(scale_fmu[0])) == []


def test_simulate_fmu_runs(scale_fmu):
    result = fmpy.simulate_fmu(str(scale_fmu[0]), stop_time=0.01, step_size=1e-3, output_interval=1e-3,
                               start_values={"u": 0.5, "k": 3.0})
    assert result["y"][-1] == pytest.approx(1.5)
    assert result["total"][-1] == pytest.approx(3.0 * 0.5 * 0.01, rel=1e-12)


def test_feedthrough_output_follows_the_input_at_once(scale):
    scale.initialize()
    for u in (0.1, -0.3, 0.7):
        scale.set(u=u)
        assert scale.get("y") == pytest.approx(2.0 * u)
    scale.step(1e-3)
    assert scale.get("total") == pytest.approx(2.0 * 0.7 * 1e-3)


@pytest.mark.parametrize("stage", ["exit_initialization", "set_input", "do_step"])
def test_errors_reach_the_master_with_a_logged_reason(scale, stage):
    scale.fmu.setupExperiment(startTime=0.0)
    scale.fmu.enterInitializationMode()
    with pytest.raises(FMICallException) as raised:
        if stage == "exit_initialization":
            scale.set(label="reject")
            scale.fmu.exitInitializationMode()
        else:
            scale.fmu.exitInitializationMode()
            if stage == "set_input":
                scale.set(u=math.nan)
            else:
                scale.set(u=2.0)
                scale.step(1e-3)
    assert raised.value.status == FMI_ERROR
    reason = {"exit_initialization": "label = 'reject' is invalid", "set_input": "u = nan is invalid",
              "do_step": "u = 2.0 is invalid"}[stage]
    (message,) = scale.errors()  # one logged line
    assert reason in message, scale.messages


FMI_DISCARD = 2

DECLINING_SCRIPT = '''
from pythonfmu import Fmi2Causality, Fmi2Slave, Real


class Declining(Fmi2Slave):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.y = 0.0
        self.register_variable(Real("y", causality=Fmi2Causality.output))

    def do_step(self, current_time, step_size):
        return False
'''


def test_a_declined_step_is_discard_so_nfal_slaves_raise_instead(tmp_path):
    """Why a failing nfal FMU raises (fmi2Error in our runtime, the test above) rather than decline a step:
    pythonfmu's runtime answers a ``do_step`` that returns False with fmi2Discard (ours keeps that), which
    would invite a master to retry a shorter step (docs/hil.md)."""
    from pythonfmu.builder import FmuBuilder

    script = tmp_path / "declining.py"
    script.write_text(DECLINING_SCRIPT, encoding="utf-8")
    fmu = FmuBuilder.build_FMU(script, dest=tmp_path)
    instance = Instance(fmu, extract(str(fmu)))
    instance.initialize()
    with pytest.raises(FMICallException) as raised:
        instance.step(1e-3)
    assert raised.value.status == FMI_DISCARD
    instance.free()


@pytest.mark.slow  # FMUs in subprocesses
def test_a_failed_instance_can_be_freed_again_and_again(scale_fmu):
    """pythonfmu 0.7.0's runtime dropped references on every exception; ours keeps them (no crash, no leak)."""
    for i in range(12):
        instance = Instance(*scale_fmu, name=f"failing{i}", logging_on=False)
        instance.fmu.setupExperiment(startTime=0.0)
        instance.fmu.enterInitializationMode()
        instance.set(k=-1.0)
        with pytest.raises(FMICallException):
            instance.fmu.exitInitializationMode()
        with pytest.raises(FMICallException):
            instance.set(u=math.nan)
        if i == 0:
            # the FMU's own NfalSlave (fmus/bundle_loader.py), not the one this process imported
            slave_type = type(next(o for o in gc.get_objects() if type(o).__name__ == "Scale"
                                   and any(c.__name__ == "NfalSlave" for c in type(o).__mro__)))
            refs_before = sys.getrefcount(slave_type)
        instance.set(k=2.0)
        instance.fmu.exitInitializationMode()  # still usable after the errors
        instance.set(u=0.5)
        assert instance.get("y") == 1.0
        instance.free()
        gc.collect()
    assert sys.getrefcount(slave_type) <= refs_before


def test_fmu_state_round_trip_reproduces_the_continuation(scale):
    scale.initialize()
    scale.set(u=0.3)
    scale.step(1e-3)
    saved = scale.fmu.getFMUstate()
    serialized = scale.fmu.serializeFMUstate(saved)
    scale.set(u=0.9)
    scale.step(1e-3)
    first = scale.get("total", "y", "u")
    scale.fmu.setFMUstate(saved)
    assert scale.get("u") == 0.3
    scale.set(u=0.9)
    scale.fmu.doStep(1e-3, 1e-3)
    assert scale.get("total", "y", "u") == first
    restored = scale.fmu.deSerializeFMUstate(serialized)
    scale.fmu.setFMUstate(restored)
    scale.set(u=0.9)
    scale.fmu.doStep(1e-3, 1e-3)
    assert scale.get("total", "y", "u") == first
    scale.fmu.freeFMUstate(saved)
    scale.fmu.freeFMUstate(restored)


def test_the_runtime_answers_the_gets_and_sets_of_a_step_from_its_value_cache(scale_fmu):
    """fmus/runtime's ValueCache: after initialisation a step's sets and the reads of the state's outputs do not
    enter Python; a computed output's first read after a set or a step does, once, and sees the new input."""
    instance = Instance(*scale_fmu, name="counted")
    try:
        instance.initialize(u=0.25)
        slave = runtime_slave("Scale", "counted")
        calls = []
        for method in ("get_real", "get_boolean", "set_real"):
            original = getattr(slave, method)
            setattr(slave, method, lambda *args, _f=original, _m=method: (calls.append(_m), _f(*args))[1])
        for k in range(3):
            instance.set(u=0.1 * (k + 1))
            instance.step(1e-3)
            total = 2.0 * 1e-3 * 0.1 * sum(range(1, k + 2))
            assert instance.get("total", "positive", "u") == (pytest.approx(total), True, pytest.approx(0.1 * (k + 1)))
        assert calls == []  # sets, a step, reads of the state's outputs and of an input: the cache's
        instance.set(u=0.5)
        assert instance.get("y") == 1.0  # computed from the input just set
        assert instance.get("y") == 1.0
        assert calls == ["get_real"]  # the first read after the set, once
        instance.step(1e-3)
        instance.get("y")
        assert calls == ["get_real", "get_real"]  # and after a step
    finally:
        instance.free()


def test_a_read_of_another_variable_does_not_compute_the_outputs_again(scale_fmu):
    """A host that reads a variable the cache does not hold (a parameter) enters the slave's Python; the computed
    outputs, up to date, are not computed again for it (they were, for every such read)."""
    instance = Instance(*scale_fmu, name="recounted")
    try:
        instance.initialize(u=0.25)
        slave = runtime_slave("Scale", "recounted")
        computed = []
        slave._cache_computed = [(slot, lambda _g=getter: (computed.append(1), _g())[1])
                                 for slot, getter in slave._cache_computed]
        instance.set(u=0.5)
        assert instance.get("y") == 1.0 and len(computed) == 1
        assert [instance.get("k") for _ in range(3)] == [2.0] * 3
        assert instance.get("y") == 1.0 and len(computed) == 1
        instance.set(u=0.25)
        assert instance.get("k") == 2.0 and instance.get("y") == 0.5 and len(computed) == 2
    finally:
        instance.free()


def test_nfal_value_cache_off_sends_every_call_to_the_slave(scale_fmu, monkeypatch):
    """VALUE_CACHE_ENV=off: the runtime binds no cache, so a step's sets and reads reach the slave's Python."""
    monkeypatch.setenv(VALUE_CACHE_ENV, "off")
    instance = Instance(*scale_fmu, name="uncached")
    try:
        instance.initialize(u=0.25)
        gc.collect()
        (slave,) = [o for o in gc.get_objects() if type(o).__name__ == "Scale" and o.instance_name == "uncached"]
        assert slave._value_cache is None
        instance.set(u=0.5)
        instance.step(1e-3)
        assert instance.get("u", "y", "total") == (0.5, 1.0, pytest.approx(1e-3))
    finally:
        instance.free()


def test_what_the_value_cache_holds_stays_what_the_slave_says(scale):
    """A tunable parameter set after initialisation moves the computed output at once; an input set to NaN is
    refused by the slave, saying why, and the input keeps its value; an input set just before getFMUstate is in
    the state; after fmi2Reset the new instance's values are served."""
    scale.initialize(u=0.2)
    assert scale.get("y") == pytest.approx(0.4)
    scale.set(offset=1.0)
    assert scale.get("y") == pytest.approx(1.4)
    with pytest.raises(FMICallException):
        scale.set(u=math.nan)
    assert "u = nan is invalid" in scale.errors()[-1]
    assert scale.get("u", "y") == (0.2, pytest.approx(1.4))
    scale.set(u=0.6)
    saved = scale.fmu.getFMUstate()
    scale.set(u=-0.6)
    scale.step(1e-3)
    scale.fmu.setFMUstate(saved)
    assert scale.get("u", "y", "total") == (0.6, pytest.approx(2.2), 0.0)
    scale.fmu.freeFMUstate(saved)
    scale.fmu.reset()
    scale.time = 0.0
    scale.initialize(u=0.1)
    scale.step(1e-3)
    assert scale.get("u", "y", "total", "positive") == (0.1, pytest.approx(0.2), pytest.approx(2e-4), True)


def _state_bytes(scale, **changes) -> bytes:
    """The instance's serialized FMU state, its JSON changed (``variables`` or ``internal``)."""
    saved = scale.fmu.getFMUstate()
    state = json.loads(bytes(scale.fmu.serializeFMUstate(saved)))
    scale.fmu.freeFMUstate(saved)
    for key, value in changes.items():
        state[key] = value(state[key]) if callable(value) else value
    return json.dumps(state).encode()


def test_the_value_cache_answers_after_a_failed_or_partial_restore_and_after_terminate(scale, scale_fmu):
    """What the slave holds, whatever the cache held: a restore that fails half-way (its variables set, its internal
    state refused) answers the restored input; a restore of a state without an input keeps the input set before it;
    an output the slave changes as it terminates is read as the slave has it."""
    scale.initialize(u=0.2)
    scale.step(1e-3)
    broken = _state_bytes(scale, internal=[])  # u = 0.2, and an internal state set_internal_state refuses
    without_u = _state_bytes(scale, variables=lambda values: {k: v for k, v in values.items() if k != "u"})
    scale.set(u=0.7)  # waits in the cache for the slave
    restored = scale.fmu.deSerializeFMUstate(broken)
    with pytest.raises(FMICallException):
        scale.fmu.setFMUstate(restored)
    assert scale.get("u", "y") == (0.2, pytest.approx(0.4))
    scale.fmu.freeFMUstate(restored)
    scale.set(u=0.7)
    restored = scale.fmu.deSerializeFMUstate(without_u)
    scale.fmu.setFMUstate(restored)
    assert scale.get("u", "y") == (0.7, pytest.approx(1.4))
    scale.fmu.freeFMUstate(restored)
    ending = Instance(*scale_fmu, name="ending")
    ending.initialize(u=0.2)
    ending.step(1e-3)
    assert ending.get("positive") == 1
    ending.fmu.terminate()
    assert ending.get("positive") == 0
    ending.fmu.freeInstance()


def test_a_damaged_serialized_state_is_an_error(scale):
    scale.initialize()
    state = scale.fmu.deSerializeFMUstate(b"not json")
    with pytest.raises(FMICallException):
        scale.fmu.setFMUstate(state)
    assert any("serialized FMU state is not valid" in message for message in scale.errors())


# --- the build ------------------------------------------------------------------------------------------
def test_the_fmu_carries_nfal(scale_fmu):
    resources = Path(scale_fmu[1]) / "resources"
    assert (resources / "slavemodule.txt").read_text().strip() == "nfal_scale"
    for relative in ("nfal/__init__.py", "nfal/fmus/__init__.py", "nfal/fmus/base.py", "nfal/models/plant.py",
                     "nfal/models/data/fig3_mode_shape_standin.csv", "nfal_scale.py", "pythonfmu/fmi2slave.py"):
        assert (resources / relative).is_file(), relative
    assert not (resources / "nfal" / "cli.py").exists()


def test_an_up_to_date_fmu_is_not_rebuilt(tmp_path, scale_script, monkeypatch):
    monkeypatch.setitem(build.FMU_SCRIPTS, "Scale", str(scale_script))
    path = build.build_fmus(tmp_path, ["Scale"])["Scale"]
    built = path.stat().st_mtime_ns
    assert build.build_fmus(tmp_path, ["Scale"])["Scale"].stat().st_mtime_ns == built
    assert build.build_fmus(tmp_path, ["Scale"], force=True)["Scale"].stat().st_mtime_ns != built


def test_unknown_fmu_names_are_refused(tmp_path):
    with pytest.raises(InvalidParameterError, match="FMU name"):
        build.build_fmus(tmp_path, ["NoSuchModel"])


SELF_CONTAINED = textwrap.dedent('''
    import sys
    sys.meta_path[:] = [f for f in sys.meta_path if not getattr(f, "__module__", "").startswith("__editable__")]
    sys.path_hooks[:] = [h for h in sys.path_hooks if not getattr(h, "__module__", "").startswith("__editable__")]
    sys.path_importer_cache.clear()
    try:
        import nfal
    except ModuleNotFoundError:
        pass
    else:
        raise SystemExit("nfal is importable outside the FMU: " + str(nfal.__file__))
    import fmpy
    result = fmpy.simulate_fmu(sys.argv[1], stop_time=0.005, step_size=5e-4, output_interval=5e-4,
                               start_values={"excitation_amplitude": 5e-6})
    (slave,) = sys.modules["_nfal_fmu_bundles"].bundles.values()  # fmus/bundle_loader.py's registry
    assert "resources" in slave.__file__, slave.__file__
    assert "nfal" not in sys.modules  # the FMU's copy stays its own
    print(len(result), result["height"][-1])
''')


@pytest.mark.slow  # FMUs in subprocesses
def test_fmu_runs_where_nfal_is_not_installed(tmp_path_factory, tmp_path):
    """Only the copy of nfal inside the FMU can serve: the editable install is hidden from the subprocess."""
    fmu = build.build_fmus(tmp_path_factory.mktemp("contained"), ["SlowPlant"])["SlowPlant"]
    done = subprocess.run([sys.executable, "-c", SELF_CONTAINED, str(fmu)], cwd=tmp_path, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-3000:] + done.stdout[-2000:]
    samples, height = done.stdout.split()
    assert int(samples) == 11 and 60e-6 < float(height) < 200e-6  # 5 um lifts the object from 60 um


@pytest.mark.parametrize("module, name", [("slow_plant", "SlowPlant"), ("controller", "Controller"),
                                          ("resonance_tracker", "ResonanceTracker"), ("sensor_chain", "SensorChain")])
def test_serialized_state_restores_into_a_fresh_instance(module, name):
    """A state saved mid-run, serialized and set into a new instance continues exactly as the original."""
    import importlib

    from pythonfmu.variables import Real

    cls = getattr(importlib.import_module(f"nfal.fmus.{module}"), name)
    original = cls(instance_name="original")
    original.enter_initialization_mode()
    original.exit_initialization_mode()
    for k in range(5):
        original.do_step(k * 5e-4, 5e-4)
    saved = cls._fmu_state_to_bytes(original._get_fmu_state())
    fresh = cls(instance_name="fresh")
    fresh._set_fmu_state(cls._fmu_state_from_bytes(saved))
    for k in range(5, 12):
        original.do_step(k * 5e-4, 5e-4)
        fresh.do_step(k * 5e-4, 5e-4)
    reals = [vr for vr, variable in original.vars.items() if isinstance(variable, Real)]
    assert fresh.get_real(reals) == original.get_real(reals)
