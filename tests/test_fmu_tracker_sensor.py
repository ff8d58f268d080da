"""ResonanceTracker and SensorChain FMUs: first as Python objects, then built with fmus/build.py and run with fmpy."""

import json
import math
import shutil

import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave
from fmpy.validation import validate_fmu

from nfal.errors import InvalidParameterError
from nfal.fmus.build import build_fmus
from nfal.fmus.resonance_tracker import ResonanceTracker
from nfal.fmus.sensor_chain import SensorChain
from nfal.models.measurement_noise import coloured_noise
from nfal.models.pll import PhaseLockedLoop, drift_ramp, simulate_tracking
from nfal.models.pll import ResonanceTracker as TrackerModel
from nfal.models.transducer import Transducer

DT = 5e-4
F_R = 28500.0
DRIFT_HZ = 0.002 * F_R
RAMP = drift_ramp(DRIFT_HZ, 0.5, start_s=0.1)


# --- Python objects ------------------------------------------------------------------------------------
class Driver:
    """Drive a slave made in Python through its FMI methods (by variable name)."""

    def __init__(self, cls, **parameters):
        self.slave = cls(instance_name="test")
        self.refs = {v.name: ref for ref, v in self.slave.vars.items()}
        self.slave.setup_experiment(0.0)
        self.slave.enter_initialization_mode()
        self.set(**parameters)

    def _method(self, name, verb):
        kind = type(self.slave.vars[self.refs[name]]).__name__.lower()
        return getattr(self.slave, f"{verb}_{kind}")

    def set(self, **values):
        for name, value in values.items():
            self._method(name, "set")([self.refs[name]], [value])
        return self

    def get(self, name):
        return self._method(name, "get")([self.refs[name]])[0]

    def start(self):
        self.slave.exit_initialization_mode()
        return self


def drive_tracker(driver, steps, voltage=100.0, shift=RAMP):
    amplitude, frequency, locked = [], [], []
    for k in range(steps):
        driver.set(drive_voltage=voltage, resonance_shift=shift(k * DT))
        amplitude.append(driver.get("excitation_amplitude"))
        frequency.append(driver.get("drive_frequency"))
        locked.append(driver.get("locked"))
        driver.slave.do_step(k * DT, DT)
    return np.array(amplitude), np.array(frequency), np.array(locked)


@pytest.mark.parametrize("dynamics", [True, False], ids=["dynamic", "quasi-static"])
@pytest.mark.parametrize("enabled", [True, False], ids=["pll", "fixed"])
def test_tracker_slave_is_the_model(dynamics, enabled):
    """The slave's outputs are the pure-Python tracker's, bit for bit, under the 0.2 % drift."""
    driver = Driver(ResonanceTracker, transducer_dynamics=dynamics,
                    pll_enabled=enabled).set(drive_voltage=100.0).start()
    amplitude, frequency, locked = drive_tracker(driver, 600)
    transducer = Transducer()
    model = TrackerModel(transducer, PhaseLockedLoop.designed(transducer, quasi_static=not dynamics, enabled=enabled),
                         dynamics=dynamics)
    run = simulate_tracking(model, 600 * DT, voltage_v=100.0, resonance_shift_hz=RAMP)
    np.testing.assert_array_equal(amplitude, run.excitation_amplitude_m)
    np.testing.assert_array_equal(frequency, run.drive_frequency_hz)
    np.testing.assert_array_equal(locked, run.locked)


def test_tracker_quasi_static_output_feeds_through_from_the_voltage():
    driver = Driver(ResonanceTracker, transducer_dynamics=False).set(drive_voltage=20.0).start()
    assert driver.get("excitation_amplitude") == pytest.approx(2e-6, rel=1e-12)
    driver.set(drive_voltage=50.0)
    assert driver.get("excitation_amplitude") == pytest.approx(5e-6, rel=1e-12)
    dynamic = Driver(ResonanceTracker).set(drive_voltage=20.0).start()
    dynamic.set(drive_voltage=50.0)
    assert dynamic.get("excitation_amplitude") == pytest.approx(2e-6, rel=1e-12)  # the state: no jump
    dynamic.slave.do_step(0.0, DT)
    assert 2e-6 < dynamic.get("excitation_amplitude") < 5e-6


def test_tracker_holds_between_pll_samples():
    """Communication step T/2: the drive frequency changes at sample instants only."""
    driver = Driver(ResonanceTracker).set(drive_voltage=100.0, resonance_shift=20.0).start()
    frequency = []
    for k in range(40):
        frequency.append(driver.get("drive_frequency"))
        driver.slave.do_step(k * DT / 2, DT / 2)
    frequency = np.array(frequency)
    np.testing.assert_array_equal(frequency[1::2], frequency[::2])
    assert frequency[-1] > F_R + 1.0


def test_sensor_slave_is_the_closed_loop_measurement():
    driver = Driver(SensorChain, analog_cutoff=0.0, seed=4).start()
    heights = 60e-6 + 30e-6 * np.sin(np.arange(800) * 0.02)
    measured = []
    for k, height in enumerate(heights):
        driver.set(true_height=height)
        measured.append(driver.get("measured_height"))
        driver.slave.do_step(k * DT, DT)
    np.testing.assert_array_equal(np.array(measured), heights + coloured_noise(800, seed=4))


@pytest.mark.parametrize("cls, parameters", [
    (ResonanceTracker, {"quality_factor": 0.3}), (ResonanceTracker, {"pll_bandwidth": 500.0}),
    (ResonanceTracker, {"lock_threshold": 2.0}), (ResonanceTracker, {"lock_samples": 0}),
    (ResonanceTracker, {"pll_rate": -1.0}), (SensorChain, {"seed": -1}), (SensorChain, {"noise_cutoff": 1500.0}),
    (SensorChain, {"noise_cutoff": 1e-6}),
    (SensorChain, {"analog_cutoff": -5.0}), (SensorChain, {"resolution": -1e-6})])
def test_bad_parameters_fail_at_the_end_of_initialisation(cls, parameters):
    driver = Driver(cls, **parameters)
    with pytest.raises(InvalidParameterError):
        driver.start()


@pytest.mark.parametrize("cls", [ResonanceTracker, SensorChain])
def test_step_longer_than_the_sample_period_fails(cls):
    driver = Driver(cls).start()
    with pytest.raises(InvalidParameterError, match="sample period"):
        driver.slave.do_step(0.0, 2 * DT)


def test_negative_drive_voltage_fails():
    driver = Driver(ResonanceTracker).start().set(drive_voltage=-1.0)
    with pytest.raises(InvalidParameterError):
        driver.slave.do_step(0.0, DT)


@pytest.mark.parametrize("cls, inputs, output", [
    (ResonanceTracker, {"drive_voltage": 60.0, "resonance_shift": 30.0}, "excitation_amplitude"),
    (SensorChain, {"true_height": 80e-6}, "measured_height")])
def test_slave_state_round_trips_through_json(cls, inputs, output):
    driver = Driver(cls).set(**inputs).start()
    for k in range(50):
        driver.slave.do_step(k * DT, DT)
    saved = driver.slave._fmu_state_from_bytes(driver.slave._fmu_state_to_bytes(driver.slave._get_fmu_state()))
    first = []
    for k in range(50, 250):
        first.append(driver.get(output))
        driver.slave.do_step(k * DT, DT)
    driver.slave._set_fmu_state(saved)
    again = []
    for k in range(50, 250):
        again.append(driver.get(output))
        driver.slave.do_step(k * DT, DT)
    assert again == first and len(set(first)) > 10


# --- built FMUs ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    return build_fmus(tmp_path_factory.mktemp("fmus"), ["ResonanceTracker", "SensorChain"])


@pytest.mark.parametrize("name", ["ResonanceTracker", "SensorChain"])
def test_fmu_validates(fmus, name):
    assert validate_fmu(str(fmus[name])) == []


CONTRACT = {
    "ResonanceTracker": {"drive_voltage": ("input", "V"), "resonance_shift": ("input", "Hz"),
                         "excitation_amplitude": ("output", "m"), "drive_frequency": ("output", "Hz"),
                         "locked": ("output", None), "phase_error": ("output", "rad"),
                         "resonance_frequency": ("parameter", "Hz"), "quality_factor": ("parameter", "1"),
                         "metres_per_volt": ("parameter", "m/V"), "transducer_dynamics": ("parameter", None),
                         "pll_enabled": ("parameter", None), "pll_rate": ("parameter", "Hz"),
                         "pll_bandwidth": ("parameter", "Hz"), "lock_threshold": ("parameter", "rad"),
                         "lock_samples": ("parameter", None)},
    "SensorChain": {"true_height": ("input", "m"), "measured_height": ("output", "m"),
                    "sample_rate": ("parameter", "Hz"),
                    "noise_peak": ("parameter", "m"), "noise_cutoff": ("parameter", "Hz"), "seed": ("parameter", None),
                    "analog_cutoff": ("parameter", "Hz"), "resolution": ("parameter", "m")},
}


@pytest.mark.parametrize("name", ["ResonanceTracker", "SensorChain"])
def test_model_description_follows_the_contract(fmus, name):
    description = read_model_description(str(fmus[name]))
    variables = {v.name: v for v in description.modelVariables}
    assert {n: (v.causality, v.unit) for n, v in variables.items()} == CONTRACT[name]
    outputs = {u.variable.name: sorted(d.name for d in u.dependencies) for u in description.outputs}
    inputs = sorted(n for n, (causality, _) in CONTRACT[name].items() if causality == "input")
    assert all(dependencies == inputs for dependencies in outputs.values())


@pytest.mark.parametrize("enabled", [True, False], ids=["pll", "fixed"])
def test_fmu_acceptance_under_0p2_percent_drift(fmus, enabled):
    """The acceptance check through fmpy: ramp 0.2 % over 0.5 s from 0.1 s, hold; PLL within 1 % after lock,
    fixed frequency below half at the end; and the same numbers as the pure-Python tracker."""
    signal = np.array([(0.0, 100.0, 0.0), (0.1, 100.0, 0.0), (0.6, 100.0, DRIFT_HZ), (1.2, 100.0, DRIFT_HZ)],
                      dtype=[("time", float), ("drive_voltage", float), ("resonance_shift", float)])
    result = simulate_fmu(str(fmus["ResonanceTracker"]), stop_time=1.2, output_interval=DT, input=signal,
                          start_values={"pll_enabled": enabled},
                          output=["excitation_amplitude", "drive_frequency", "locked"])
    ratio = result["excitation_amplitude"] / 10e-6
    if enabled:
        first = int(np.argmax(result["locked"]))
        assert result["locked"][first] and np.all(np.abs(ratio[first:] - 1) < 0.01)
    else:
        assert not result["locked"].any() and ratio[-1] < 0.5
    transducer = Transducer()
    model = TrackerModel(transducer, PhaseLockedLoop.designed(transducer, enabled=enabled))
    run = simulate_tracking(model, 1.2, voltage_v=100.0, resonance_shift_hz=RAMP)
    np.testing.assert_allclose(result["excitation_amplitude"][:-1], run.excitation_amplitude_m, rtol=1e-9)


def test_fmu_sensor_is_the_closed_loop_measurement(fmus):
    result = simulate_fmu(str(fmus["SensorChain"]), stop_time=0.5, output_interval=DT,
                          start_values={"analog_cutoff": 0.0, "seed": 9, "true_height": 75e-6},
                          output=["measured_height"])
    np.testing.assert_array_equal(result["measured_height"][:1000], 75e-6 + coloured_noise(1000, seed=9))


def test_fmu_sensor_filter_and_quantiser(fmus):
    """Default Table 2 filter, 1 um resolution, no noise: a step 60 -> 90 um settles on the grid with ~no overshoot."""
    signal = np.array([(0.0, 60e-6), (0.01, 60e-6), (0.01, 90e-6), (0.05, 90e-6)],
                      dtype=[("time", float), ("true_height", float)])
    result = simulate_fmu(str(fmus["SensorChain"]), stop_time=0.05, output_interval=DT, input=signal,
                          start_values={"noise_peak": 0.0, "resolution": 1e-6}, output=["measured_height"])
    measured = result["measured_height"]
    np.testing.assert_allclose(measured / 1e-6, np.round(measured / 1e-6), atol=1e-9)
    assert measured[0] == pytest.approx(60e-6) and measured[-1] == pytest.approx(90e-6)
    assert np.max(measured) <= 91e-6 + 1e-12


def _instance(path, tmp_path, name):
    description = read_model_description(str(path))
    folder = extract(str(path), unzipdir=str(tmp_path / name))
    fmu = FMU2Slave(guid=description.guid, unzipDirectory=folder,
                    modelIdentifier=description.coSimulation.modelIdentifier, instanceName=name)
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    refs = {v.name: v.valueReference for v in description.modelVariables}
    return fmu, refs, folder


@pytest.mark.parametrize("name, inputs, output", [
    ("ResonanceTracker", {"drive_voltage": 60.0, "resonance_shift": 30.0}, "excitation_amplitude"),
    ("SensorChain", {"true_height": 80e-6}, "measured_height")])
def test_fmu_state_get_set_and_serialize(fmus, tmp_path, name, inputs, output):
    fmu, refs, folder = _instance(fmus[name], tmp_path, name)
    fmu.setReal([refs[n] for n in inputs], list(inputs.values()))
    fmu.exitInitializationMode()

    def run(start, steps):
        values = []
        for k in range(start, start + steps):
            values.append(fmu.getReal([refs[output]])[0])
            fmu.doStep(k * DT, DT)
        return values

    run(0, 40)
    state = fmu.getFMUstate()
    serialized = fmu.serializeFMUstate(state)
    first = run(40, 200)
    fmu.setFMUstate(state)
    assert run(40, 200) == first
    fmu.setFMUstate(fmu.deSerializeFMUstate(serialized))
    assert run(40, 200) == first
    assert json.loads(bytes(serialized).decode())["model"] == name
    fmu.freeFMUstate(state)
    fmu.terminate()
    fmu.freeInstance()
    shutil.rmtree(folder, ignore_errors=True)


@pytest.mark.parametrize("name", ["ResonanceTracker", "SensorChain"])
def test_fmu_answers_a_too_long_step_with_an_error_and_can_be_freed(fmus, tmp_path, name):
    fmu, refs, folder = _instance(fmus[name], tmp_path, name)
    fmu.exitInitializationMode()
    with pytest.raises(FMICallException):
        fmu.doStep(0.0, 3 * DT)
    fmu.freeInstance()
    shutil.rmtree(folder, ignore_errors=True)


def test_fmu_tracker_feedthrough_at_the_communication_point(fmus, tmp_path):
    """Quasi-static: setting drive_voltage changes excitation_amplitude before any doStep (dependencies are real)."""
    fmu, refs, folder = _instance(fmus["ResonanceTracker"], tmp_path, "feedthrough")
    fmu.setBoolean([refs["transducer_dynamics"]], [False])
    fmu.exitInitializationMode()
    for voltage in (10.0, 40.0):
        fmu.setReal([refs["drive_voltage"]], [voltage])
        assert fmu.getReal([refs["excitation_amplitude"]])[0] == pytest.approx(voltage * 0.1e-6, rel=1e-12)
    assert fmu.getReal([refs["phase_error"]])[0] == pytest.approx(0.0, abs=1e-12)
    assert math.isclose(fmu.getReal([refs["drive_frequency"]])[0], F_R)
    fmu.terminate()
    fmu.freeInstance()
    shutil.rmtree(folder, ignore_errors=True)


# --- the ResonanceTracker's compiled core (models/tracker_core.py) ----------------------------------------------
#: (drive voltage [V], resonance shift [Hz]) per step: locking, a drift, no drive (below the PLL's least amplitude),
#: a drive again.
TRACKER_SCENARIO = [(100.0, RAMP(k * DT)) for k in range(300)] + [(0.0, 40.0)] * 20 + [(60.0, 40.0)] * 80


@pytest.fixture
def tracker(fmus, tmp_path):
    import numba  # noqa: F401 - the slave offers its core only where numba runs already (a plant's)
    from helpers.fmu_instance import Instance

    instance = Instance(fmus["ResonanceTracker"], extract(str(fmus["ResonanceTracker"]), str(tmp_path / "rt")))
    yield instance
    instance.free()


@pytest.mark.parametrize("pll_rate", [2000.0, 500.0], ids=["every-step", "every-4th-step"])
def test_the_trackers_compiled_core_steps_as_its_python(tracker, pll_rate):
    """The runtime steps the FMU with the compiled core (the slave's Python do_step is not called), and every output
    is the Python slave's to the bit: locking, a drift, no drive, a drive again, with the PLL sampled at every step
    and at every fourth; and across an FMU state saved and restored."""
    from helpers.fmu_instance import python_do_steps

    python = Driver(ResonanceTracker, pll_rate=pll_rate).start()
    tracker.initialize(pll_rate=pll_rate)
    calls = python_do_steps("ResonanceTracker")
    names = ("excitation_amplitude", "drive_frequency", "locked", "phase_error")
    saved, locked = None, []
    for k, (voltage, shift) in enumerate(TRACKER_SCENARIO):
        tracker.set(drive_voltage=voltage, resonance_shift=shift)
        python.set(drive_voltage=voltage, resonance_shift=shift)
        tracker.step(DT)
        python.slave.do_step(k * DT, DT)
        assert tracker.get(*names) == tuple(python.get(name) for name in names), k
        locked.append(python.get("locked"))
        if k == 150:
            saved, state, at = tracker.fmu.getFMUstate(), python.slave._get_fmu_state(), tracker.time
    assert calls == [] and any(locked) and not all(locked)
    tracker.fmu.setFMUstate(saved)
    python.slave._set_fmu_state(state)
    tracker.time = at
    for k in range(40):
        tracker.set(drive_voltage=90.0, resonance_shift=10.0)
        python.set(drive_voltage=90.0, resonance_shift=10.0)
        tracker.step(DT)
        python.slave.do_step(at + k * DT, DT)
        assert tracker.get(*names) == tuple(python.get(name) for name in names), k
    tracker.fmu.freeFMUstate(saved)


@pytest.mark.parametrize("inputs, reason", [
    ({"drive_voltage": 2000.0}, "drive_voltage = 2000.0 is invalid"),
    ({"drive_voltage": -1.0}, "drive_voltage = -1.0 is invalid"),
    ({"resonance_shift": 20000.0}, "resonance_shift = 20000.0 is invalid")])
def test_the_trackers_core_leaves_a_refused_input_to_the_slave(tracker, inputs, reason):
    """A finite input the slave refuses: the core declines the step, the slave's Python says why (one logged error,
    fmi2Error from doStep) and keeps the state the core stepped to."""
    tracker.initialize(drive_voltage=100.0)
    for _ in range(5):
        tracker.step(DT)  # the core's
    before = tracker.get("excitation_amplitude", "drive_frequency")
    tracker.set(**inputs)
    with pytest.raises(FMICallException) as raised:
        tracker.step(DT)
    assert (raised.value.function, raised.value.status) == ("fmi2DoStep", 3)
    (error,) = tracker.errors()
    assert reason in error and tracker.get("excitation_amplitude", "drive_frequency") == before


def test_the_trackers_core_leaves_a_step_that_misses_the_pll_samples_to_the_slave(tracker):
    tracker.initialize(drive_voltage=100.0)
    tracker.step(DT)
    with pytest.raises(FMICallException):
        tracker.step(0.3e-3)
    (error,) = tracker.errors()
    assert "communication step size" in error


# --- the SensorChain's compiled core (models/sensor_core.py) --------------------------------------------------
@pytest.fixture
def sensor(fmus, tmp_path):
    import numba  # noqa: F401 - the slave offers its core only where numba runs already (a plant's)
    from helpers.fmu_instance import Instance

    instance = Instance(fmus["SensorChain"], extract(str(fmus["SensorChain"]), str(tmp_path / "sc")))
    yield instance
    instance.free()


@pytest.mark.parametrize("parameters", [{"seed": 4}, {"noise_peak": 0.0},
                                        {"sample_rate": 1000.0, "noise_cutoff": 200.0, "seed": 1}],
                         ids=["noise", "no-noise", "every-2nd-step"])
def test_the_sensors_compiled_core_steps_as_its_python(sensor, parameters):
    """Behind the analog filter the runtime steps the FMU with the compiled core: the slave's Python steps only where
    the core has no noise left (a new block of 256 every 256 samples) or no discretisation for the step size (the
    first step, and a step of another size), and every reading is the Python slave's to the bit; across an FMU state
    saved and restored too."""
    from helpers.fmu_instance import python_do_steps

    python = Driver(SensorChain, **parameters).start()
    sensor.initialize(**parameters)
    calls = python_do_steps("SensorChain")
    heights = 80e-6 + 20e-6 * np.sin(np.arange(700) / 40.0)
    sizes = [DT] * 600 + [DT / 2] * 100  # a new step size: a new discretisation
    saved, time = None, 0.0
    for k, (height, size) in enumerate(zip(heights, sizes)):
        sensor.set(true_height=height)
        python.set(true_height=height)
        sensor.step(size)
        python.slave.do_step(time, size)
        time += size
        assert sensor.get("measured_height") == python.get("measured_height"), k
        if k == 300:
            saved, state, at = sensor.fmu.getFMUstate(), python.slave._get_fmu_state(), sensor.time
    assert 0 < len(calls) <= 8, len(calls)  # the first step, the blocks' ends (600 samples or 150), the new size
    sensor.fmu.setFMUstate(saved)
    python.slave._set_fmu_state(state)
    sensor.time = at
    for k in range(300):
        sensor.set(true_height=90e-6)
        python.set(true_height=90e-6)
        sensor.step(DT)
        python.slave.do_step(at + k * DT, DT)
        assert sensor.get("measured_height") == python.get("measured_height"), k
    sensor.fmu.freeFMUstate(saved)


def test_the_sensors_core_leaves_a_refused_height_to_the_slave(sensor):
    sensor.initialize(true_height=80e-6)
    for _ in range(5):
        sensor.step(DT)
    before = sensor.get("measured_height")
    sensor.set(true_height=1.0)  # a metre: a unit slip
    with pytest.raises(FMICallException):
        sensor.step(DT)
    (error,) = sensor.errors()
    assert "true_height = 1.0 is invalid" in error and sensor.get("measured_height") == before


@pytest.mark.parametrize("cls, inputs, output", [(SensorChain, {"true_height": 1.0}, "measured_height"),
                                                 (ResonanceTracker, {"drive_voltage": 2000.0}, "excitation_amplitude")])
def test_an_output_of_the_state_reads_no_input_and_the_step_refuses_it(cls, inputs, output):
    """Behind the analog filter, or with the transducer's dynamics, the output is the state's (what the runtime serves
    from its buffer): a read after an input the slave refuses gives the state's value, and the step refuses it."""
    driver = Driver(cls).start()
    driver.slave.do_step(0.0, DT)
    before = driver.get(output)
    driver.set(**inputs)
    assert driver.get(output) == before
    with pytest.raises(InvalidParameterError):
        driver.slave.do_step(DT, DT)


@pytest.mark.parametrize("name", ["tracker", "sensor"])
def test_a_core_leaves_the_steps_of_a_state_from_before_initialisation_to_the_slave(request, name):
    """An FMU state taken before initialisation ended, restored after the core stepped: the slave's doStep refuses the
    step (as its Python does), where the core would have stepped its old state."""
    from helpers.fmu_instance import refuses_a_state_from_before_initialisation

    assert refuses_a_state_from_before_initialisation(request.getfixturevalue(name), DT)
