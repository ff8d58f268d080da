"""Controller FMU (fmus/controller.py): outputs equal DiscreteControlLaw.step on the same inputs, sampled at
its own rate with feedthrough at sample instants, bumpless start, input checks and FMU state."""

from __future__ import annotations

import math

import fmpy
import numpy as np
import pytest
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu
from helpers.fmu_instance import FMI_ERROR, Instance, build_and_extract

from nfal.errors import DataFormatError, InvalidParameterError
from nfal.fmus.rig_contract import rig_parameter_values
from nfal.fmus.controller import Controller
from nfal.fmus.reynolds_plant import ReynoldsPlant
from nfal.models.calibration import RigCalibration, paper_calibration, perturbation_calibration
from nfal.models.control_law import LIFT_OFF_TIME_S, DiscreteControlLaw
from nfal.models.damping import DampingCorrection
from nfal.models.excitation import parse_shape
from nfal.models.pid_design import DesignSpec, design_schedule, fixed_design
from nfal.models.plant import ExcessDamping, SimplifiedPlant
from nfal.models.rig import RigParameters
from nfal.models.table2 import REFERENCE_ZERO_RATIO
from nfal.models.transducer import Transducer

RIG = RigParameters()
PERIOD = 5e-4  # 2 kHz
METRES_PER_VOLT = 0.1e-6
RNG = np.random.default_rng(7)
#: The Controller's default design: the sampled placement, with the law's reference zero.
DEFAULT_SPEC = DesignSpec(10.0, 300.0, 2000.0, REFERENCE_ZERO_RATIO)
# (reference, measured) per sample: a reference step and a measured height that wanders about it
REFERENCES = np.repeat([60e-6, 100e-6, 80e-6], 20)
MEASURED = REFERENCES + RNG.normal(0.0, 3e-6, REFERENCES.size) + np.linspace(-10e-6, 10e-6, REFERENCES.size)


def make_law(design="gain-scheduled"):
    calibration, spec = paper_calibration(), DEFAULT_SPEC
    if design == "fixed":
        gains = fixed_design(120e-6, RIG, calibration, spec)
    else:
        gains = design_schedule(None, RIG, calibration, spec)
    return DiscreteControlLaw(gains, sample_rate_hz=2000.0, max_excitation_m=10e-6, reference_range_m=(50e-6, 200e-6),
                              lift_off_time_s=LIFT_OFF_TIME_S, actuator_lag_s=Transducer().time_constant_s(),
                              reference_zero_ratio=REFERENCE_ZERO_RATIO)


def reference_commands(law, references, measured):
    start = float(references[0])
    state = law.initial_state(start, float(SimplifiedPlant(RIG, paper_calibration()).equilibrium_excitation(start)))
    out = []
    for r, h in zip(references, measured):
        command, state = law.step(state, float(r), float(h))
        out.append(command)
    return np.array(out)


@pytest.fixture(scope="module")
def fmu(tmp_path_factory):
    return build_and_extract(tmp_path_factory, "Controller")["Controller"]


@pytest.fixture()
def controller(fmu):
    instance = Instance(*fmu)
    yield instance
    instance.free()


@pytest.fixture(scope="module")
def law():
    return make_law()


# --- as a Python object ---------------------------------------------------------------------------------
def initialised(**parameters) -> Controller:
    slave = Controller(instance_name="controller")
    for name, value in parameters.items():
        setattr(slave, name, value)
    slave.setup_experiment(0.0)
    slave.exit_initialization_mode()
    return slave


def test_object_outputs_equal_the_law(law):
    slave = initialised(reference=float(REFERENCES[0]))
    expected = reference_commands(law, REFERENCES, MEASURED)
    for k, (r, h) in enumerate(zip(REFERENCES, MEASURED)):
        slave.reference, slave.measured_height = float(r), float(h)
        assert slave._command() == expected[k]
        assert slave._voltage() == expected[k] / METRES_PER_VOLT
        slave.do_step(k * PERIOD, PERIOD)


def test_bumpless_start_at_the_reference_equilibrium():
    slave = initialised(reference=100e-6, measured_height=100e-6)
    equilibrium = float(SimplifiedPlant(RIG, paper_calibration()).equilibrium_excitation(100e-6))
    assert slave._command() == pytest.approx(equilibrium, rel=1e-12)


def test_holds_between_sample_instants(law):
    """Communication every 0.25 ms: outputs are law(state, inputs) at sample instants, held in between."""
    slave = initialised(reference=float(REFERENCES[0]))
    expected = reference_commands(law, REFERENCES[:10], MEASURED[:10])
    for k in range(10):
        slave.reference, slave.measured_height = float(REFERENCES[k]), float(MEASURED[k])
        assert slave._command() == expected[k]
        slave.do_step(k * PERIOD, PERIOD / 2)
        slave.measured_height = 150e-6  # ignored until the next sample instant
        assert slave._command() == expected[k]
        slave.do_step(k * PERIOD + PERIOD / 2, PERIOD / 2)


def test_fixed_design_uses_one_gain_set():
    slave = initialised(design="fixed", reference=float(REFERENCES[0]))
    expected = reference_commands(make_law("fixed"), REFERENCES, MEASURED)
    for k, (r, h) in enumerate(zip(REFERENCES, MEASURED)):
        slave.reference, slave.measured_height = float(r), float(h)
        assert slave._command() == expected[k]
        slave.do_step(k * PERIOD, PERIOD)
    assert slave.law.name == "linear at 120 um"


def test_realizable_only_false_keeps_the_full_schedule():
    assert initialised(placement="continuous", realizable_only=False).law.name == "gain-scheduled"
    assert initialised(placement="continuous").law.name == "gain-scheduled from 90 um"


@pytest.mark.parametrize("height", [50e-6, 77e-6, 140e-6, 200e-6])
def test_sampled_placement_schedules_the_sampled_designs_without_holding(height):
    slave = initialised()
    expected = design_schedule(None, RIG, paper_calibration(), DEFAULT_SPEC)
    np.testing.assert_allclose(slave.law.gains.gains_si(height), expected.gains_si(height), rtol=1e-12)
    assert slave.law.name == "gain-scheduled from 50 um"


@pytest.fixture()
def identified(tmp_path):
    """A calibration file as nfal identify writes it: K, a damping table, the rig, provenance."""
    heights = np.array([50e-6, 80e-6, 110e-6, 140e-6, 170e-6, 200e-6])
    table = DampingCorrection(heights, ExcessDamping.rig_like().factor(heights))
    path = tmp_path / "identified.json"
    RigCalibration(paper_calibration(), table, {"mass": RIG.mass, "frequency": RIG.frequency}, {"port": "loop://"}).save(path)
    return str(path), table


def test_calibration_file_damping_enters_the_design(identified):
    path, table = identified
    slave = initialised(calibration=path, placement="sampled")
    expected = design_schedule(None, RIG, paper_calibration(), DEFAULT_SPEC, damping=table)
    plain = design_schedule(None, RIG, paper_calibration(), DEFAULT_SPEC)
    np.testing.assert_allclose(slave.law.gains.gains_si(180e-6), expected.gains_si(180e-6), rtol=1e-12)
    assert not np.allclose(slave.law.gains.gains_si(180e-6), plain.gains_si(180e-6), rtol=1e-3)


def test_calibration_file_of_another_rig_is_refused(identified):
    with pytest.raises(DataFormatError, match=r"another rig \(mass 0.1347 there, 0.2 here"):
        initialised(calibration=identified[0], mass=0.2)


def test_every_slave_reads_a_calibration_file_with_the_rig_check(identified):
    """build_calibration (the ReynoldsPlant's lift-off model, any slave) goes through the same reader as the design."""
    slave = ReynoldsPlant(instance_name="plant")
    slave.calibration, slave.mass = identified[0], 0.2
    with pytest.raises(DataFormatError, match="another rig"):
        slave.build_calibration()


@pytest.mark.parametrize("parameters, reason", [
    ({"design": "adaptive"}, "design = 'adaptive'"),
    ({"placement": "hybrid"}, "placement = 'hybrid'"),
    ({"reference_min": 120e-6, "reference_max": 100e-6}, "reference_max"),
    ({"reference": 300e-6}, "reference = 0.0003"),
    ({"sample_rate": -1.0}, "sample_rate"),
    ({"metres_per_volt": 0.0}, "metres_per_volt"),
    ({"reference_max": 200.0}, r"reference_max = 200.0 is invalid: must be a clearance within 1.0–1000.0 µm"),
    ({"reference_min": 50.0}, r"reference_min = 50.0 is invalid: must be a clearance within 1.0–1000.0 µm"),
    ({"design": "fixed", "design_height": 120.0}, r"design_height = 120.0 is invalid: must be a clearance"),
    ({"nominal_frequency": 28.5}, r"nominal_frequency = 28.5 is invalid: .*kHz as Hz"),
])
def test_object_rejects_bad_parameters(parameters, reason):
    with pytest.raises(InvalidParameterError, match=reason):
        initialised(**parameters)


def test_object_rejects_a_step_longer_than_the_sample_period():
    slave = initialised()
    with pytest.raises(InvalidParameterError, match="sample period"):
        slave.do_step(0.0, 2 * PERIOD)


# --- built and run with fmpy -------------------------------------------------------------------------------
def test_controller_fmu_validates(fmu):
    assert validate_fmu(str(fmu[0])) == []


def test_fmu_outputs_equal_the_law(controller, law):
    controller.initialize(reference=float(REFERENCES[0]))
    expected = reference_commands(law, REFERENCES, MEASURED)
    for k, (r, h) in enumerate(zip(REFERENCES, MEASURED)):
        controller.set(reference=float(r), measured_height=float(h))
        command, voltage = controller.get("excitation_command", "drive_voltage")
        assert command == expected[k] and voltage == expected[k] / METRES_PER_VOLT
        controller.step(PERIOD)


def test_fmu_feedthrough_is_consistent_at_a_communication_point(controller, law):
    """Setting the measurement and reading at the same instant gives law(state, new inputs), any number of times."""
    controller.initialize(reference=100e-6, measured_height=100e-6)
    state = law.initial_state(100e-6, float(SimplifiedPlant(RIG, paper_calibration()).equilibrium_excitation(100e-6)))
    for measured in (95e-6, 105e-6, 101e-6):
        controller.set(measured_height=measured)
        assert controller.get("excitation_command") == law.step(state, 100e-6, measured)[0]
    controller.step(PERIOD)  # commits law(state, 100 um, 101 um)
    state = law.step(state, 100e-6, 101e-6)[1]
    assert controller.get("excitation_command") == law.step(state, 100e-6, 101e-6)[0]


def test_fmu_simulates_with_fmpy(fmu):
    result = fmpy.simulate_fmu(str(fmu[0]), stop_time=0.01, step_size=PERIOD, output_interval=PERIOD,
                               start_values={"reference": 100e-6, "measured_height": 100e-6})
    equilibrium = float(SimplifiedPlant(RIG, paper_calibration()).equilibrium_excitation(100e-6))
    np.testing.assert_allclose(result["excitation_command"], equilibrium, rtol=1e-12)


@pytest.mark.parametrize("inputs, reason", [
    ({"reference": 250e-6}, "reference = 0.00025 m is invalid"),
    ({"reference": 40e-6}, "reference = 4e-05 m is invalid: must be within reference_min–reference_max, "
                           "50.0–200.0 µm (5e-05–0.0002 m: a clearance in metres)"),
    ({"measured_height": math.nan}, "measured_height = nan is invalid"),
    ({"reference": math.inf}, "reference = inf is invalid"),
])
def test_fmu_bad_input_is_an_error(controller, inputs, reason):
    controller.initialize()
    with pytest.raises(FMICallException) as raised:
        controller.set(**inputs)
        controller.get("excitation_command")
    assert raised.value.status == FMI_ERROR
    assert any(reason in message for message in controller.errors()), controller.messages


def test_fmu_bad_parameter_is_an_error(controller):
    with pytest.raises(FMICallException):
        controller.initialize(design="adaptive")
    assert any("design = 'adaptive' is invalid" in message for message in controller.errors())


@pytest.mark.parametrize("step_s", [1e-3, 3e-4])
def test_fmu_rejects_a_step_that_does_not_divide_the_sample_period(controller, step_s):
    """Longer: samples skipped; 0.3 ms: sampled only every 1.5 ms (667 Hz). One logged line, fmi2Error."""
    controller.initialize()
    with pytest.raises(FMICallException) as raised:
        controller.step(step_s)
    assert raised.value.status == FMI_ERROR
    assert controller.errors() == [f"instance: communication step size = {step_s:g} is invalid: must be the sample "
                                   "period 0.0005 s divided by a whole number (e.g. 0.0005 s or 0.00025 s) "
                                   "(in doStep at t = 0 s)"]
    controller.step(PERIOD)  # the instance is whole: a valid step goes on


def test_fmu_state_round_trip(controller):
    controller.initialize(reference=float(REFERENCES[0]))
    for r, h in zip(REFERENCES[:15], MEASURED[:15]):
        controller.set(reference=float(r), measured_height=float(h))
        controller.step(PERIOD)
    saved = controller.fmu.serializeFMUstate(controller.fmu.getFMUstate())
    time = controller.time

    def continuation():
        out = []
        for r, h in zip(REFERENCES[15:40], MEASURED[15:40]):
            controller.set(reference=float(r), measured_height=float(h))
            out.append(controller.get("excitation_command"))
            controller.step(PERIOD)
        return out

    first = continuation()
    controller.fmu.setFMUstate(controller.fmu.deSerializeFMUstate(saved))
    controller.time = time
    assert continuation() == first


def test_long_saturation_is_counted_and_warned_once():
    """Measured far below the reference: the drive sits at max_excitation; saturated_time counts it, one
    warning goes to the FMU log at saturation_warning_time, and a return below the limit for longer than
    SATURATION_GAP_S ends the episode."""
    slave = initialised(reference=100e-6, measured_height=100e-6, saturation_warning_time=0.01, max_excitation=5e-6,
                        lift_off_time=0.0)  # 20 um at the first sample would otherwise be a lift-off, not saturated
    logged = []
    slave.log = lambda message, status=None, *args: logged.append((message, status))
    slave.measured_height = 20e-6
    for k in range(40):  # 20 ms at the limit
        slave.do_step(k * PERIOD, PERIOD)
    assert slave._saturated_time() == pytest.approx(40 * PERIOD)
    assert len([m for m, _ in logged if "drive saturated" in m]) == 1
    assert "reference 100 um is out of reach" in logged[0][0]
    slave.measured_height = 300e-6  # far above: the command falls to 0
    for k in range(40, 120):
        slave.do_step(k * PERIOD, PERIOD)
    assert slave._saturated_time() == 0.0


@pytest.mark.parametrize("calibration, shape", [("perturbation", "paper"), ("perturbation:piston", "piston")])
def test_perturbation_calibration_names_a_shape(calibration, shape):
    slave = Controller(instance_name="controller")
    slave.calibration = calibration
    expected = perturbation_calibration(parse_shape(shape))
    assert slave.build_calibration()(96.0) == pytest.approx(float(expected(96.0)), rel=1e-12)


def test_rig_parameter_values_are_what_build_rig_reads_back():
    rig = RigParameters(mass=0.2, radius=0.04, frequency=30e3, viscosity=1.9e-5, ambient_pressure=9e4, gravity=9.8)
    slave = Controller(instance_name="controller")
    for name, value in rig_parameter_values(rig).items():
        setattr(slave, name, value)
    assert slave.build_rig() == rig.replace(reference_clearance=RigParameters().reference_clearance)
