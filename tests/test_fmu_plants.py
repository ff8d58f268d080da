"""SlowPlant and ReynoldsPlant FMUs (fmus/slow_plant.py, fmus/reynolds_plant.py) and the stepping API of
CoupledModel they use: each checked against the pure-Python model stepped the same way."""

from __future__ import annotations

import math
import subprocess
import sys

import fmpy
import numpy as np
import pytest
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu
from helpers.fmu_instance import (FMI_ERROR, Instance, build_and_extract, python_do_steps,
                                  refuses_a_state_from_before_initialisation)

from nfal.errors import GapClosedError, InvalidParameterError
from nfal.fmus.reynolds_plant import ReynoldsPlant
from nfal.fmus.slow_plant import SlowPlant
from nfal.models.averaged_plant import AveragedFilmPlant
from nfal.models.calibration import paper_calibration
from nfal.models.coupled import CoupledModel
from nfal.models.excitation import paper_shape
from nfal.models.film_backends import TimeMarchingFilm
from nfal.models.fixed_step_plant import FixedStepPlant
from nfal.models.plant import PlantState, SimplifiedPlant
from nfal.models.rig import RigParameters

RIG = RigParameters()
STEP = 5e-4  # 2 kHz communication step
# |a| per step: hold near 60 um, step up, down; the equilibrium at 60 um needs ~1.5 um
EXCITATIONS = [2.2e-6] * 20 + [4.0e-6] * 20 + [1.0e-6] * 20


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    return build_and_extract(tmp_path_factory, "SlowPlant", "ReynoldsPlant")


@pytest.fixture()
def slow(fmus):
    instance = Instance(*fmus["SlowPlant"])
    yield instance
    instance.free()


@pytest.fixture()
def reynolds(fmus):
    instance = Instance(*fmus["ReynoldsPlant"])
    yield instance
    instance.free()


def reference_slow(excitations, frequencies=None, height=60e-6, velocity=0.0):
    """FixedStepPlant stepped with the held inputs, rebuilt when the frequency changes."""
    frequencies = frequencies or [RIG.frequency] * len(excitations)
    state, built_for, stepper, out = PlantState(height, velocity), None, None, []
    for a, f in zip(excitations, frequencies):
        if f != built_for:
            stepper, built_for = FixedStepPlant(SimplifiedPlant(RIG.replace(frequency=f), paper_calibration())), f
        state = stepper.advance(state, a, STEP)
        out.append((state.height, state.velocity))
    return np.array(out)


# --- CoupledModel's stepping API --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def coupled():
    return CoupledModel(RIG, paper_shape(), nodes=41, steps_per_period=64)


def test_advance_reproduces_simulate_over_period_aligned_steps(coupled):
    """Steps of 10 periods with |a| held over each equal simulate() with that excitation, to the last bit."""
    levels = [7e-6, 6e-6, 7.5e-6, 7e-6]
    f = RIG.frequency
    trajectory = coupled.simulate(40 / f, lambda t: levels[int(round(t * f)) // 10], 60e-6)
    state = coupled.initial_state(60e-6, 0.0, levels[0])
    for k, level in enumerate(levels):
        state = coupled.advance(state, level, 10 / f)
        last = 10 * k + 9
        assert (state.height, state.velocity, state.oscillation) == \
            (trajectory.height[last], trajectory.velocity[last], trajectory.oscillation[last])
    assert state.period_index == 40


def test_advance_reproduces_simulate_over_2khz_steps(coupled):
    """0.5 ms steps (14.25 periods): every period starting in a step uses that step's |a|."""
    levels = [7e-6, 6.5e-6, 7.2e-6, 7e-6]
    trajectory = coupled.simulate(len(levels) * STEP, lambda t: levels[min(int(t / STEP + 1e-9), len(levels) - 1)],
                                  60e-6)
    state = coupled.initial_state(60e-6, 0.0, levels[0])
    for level in levels:
        state = coupled.advance(state, level, STEP)
    assert state.period_index == trajectory.height.size == 57
    assert state.height == trajectory.height[-1] and state.oscillation == trajectory.oscillation[-1]


def test_a_step_inside_one_period_only_moves_the_time_on(coupled):
    state = coupled.advance(coupled.initial_state(60e-6, 0.0, 7e-6), 7e-6, 1.0 / RIG.frequency)
    later = coupled.advance(state, 7e-6, 0.3 / RIG.frequency)
    assert later.period_index == state.period_index + 1  # the period starting at 1/f lies in the step
    again = coupled.advance(later, 7e-6, 0.3 / RIG.frequency)
    assert again.period_index == later.period_index and again.vector is later.vector


def test_envelope_following_within_a_long_step_stays_close(coupled):
    """One 10 ms step (285 periods): envelope following against marching every period, within 0.1 um."""
    follower = CoupledModel(RIG, paper_shape(), nodes=41, steps_per_period=64, envelope=True)
    start = coupled.initial_state(70e-6, 0.0, 7e-6)
    marched = coupled.advance(start, 7e-6, 0.01)
    followed = follower.advance(start, 7e-6, 0.01)
    assert followed.height == pytest.approx(marched.height, abs=1e-7)


def test_adopt_carries_the_state_to_a_new_frequency(coupled):
    state = coupled.advance(coupled.initial_state(60e-6, 0.0, 7e-6), 7e-6, STEP)
    faster = CoupledModel(RIG.replace(frequency=RIG.frequency * 1.001), paper_shape(), nodes=41, steps_per_period=64)
    moved = faster.adopt(state, coupled)
    assert moved.epoch_s == pytest.approx(state.period_index / RIG.frequency) and moved.period_index == 0
    nodes = coupled.nodes
    assert moved.vector[2 * nodes] == state.vector[2 * nodes]  # Z kept
    assert moved.vector[2 * nodes + 2] == pytest.approx(state.vector[2 * nodes + 2] / 1.001)  # W = dZ/dT rescaled
    same = faster.advance(moved, 7e-6, STEP)
    plain = coupled.advance(state, 7e-6, STEP)
    assert same.height == pytest.approx(plain.height, rel=1e-4)  # 0.1 % faster drive, nearly the same motion


def test_adopt_refuses_another_geometry(coupled):
    other = CoupledModel(RIG, paper_shape(), nodes=21, steps_per_period=64)
    with pytest.raises(InvalidParameterError, match="previous"):
        other.adopt(coupled.initial_state(60e-6), coupled)


@pytest.mark.parametrize("kwargs, name", [({"amplitude": -1e-6}, "amplitude"), ({"velocity": math.nan}, "velocity"),
                                          ({"height": 0.0}, "height")])
def test_initial_state_checks_its_input(coupled, kwargs, name):
    arguments = {"height": 60e-6, **kwargs}
    with pytest.raises(InvalidParameterError, match=name):
        coupled.initial_state(**arguments)


def test_a_closing_gap_is_a_gap_closed_error(coupled):
    with pytest.raises(GapClosedError, match="gap closed"):
        coupled.advance(coupled.initial_state(12e-6, 0.0, 0.0), 10e-6, STEP)


# --- SlowPlant --------------------------------------------------------------------------------------------
def test_slow_plant_object_steps_like_fixed_step_plant():
    slave = SlowPlant(instance_name="slow")
    slave.setup_experiment(0.0)
    slave.exit_initialization_mode()
    out = []
    for k, a in enumerate(EXCITATIONS):
        slave.excitation_amplitude = a
        slave.do_step(k * STEP, STEP)
        out.append((slave.height, slave.velocity))
    np.testing.assert_array_equal(np.array(out), reference_slow(EXCITATIONS))


def test_the_slow_plant_compiles_its_kernels_at_set_up_unless_the_host_declares_a_short_run(monkeypatch):
    """A declared stop time within python_steps steps of 0.5 ms leaves the kernels Python for that many steps (then
    they are compiled all the same); no stop time, or a later one, compiles them at set-up, and so does a short run in
    a process that has imported numba already."""
    longest = SlowPlant.python_steps * STEP

    def planned(stop):
        slave = SlowPlant(instance_name="plant")
        slave.setup_experiment(0.0, stop)
        slave.exit_initialization_mode()
        return slave

    import numba  # noqa: F401 - on use: a process that has it compiles even a short run (little more than a load)

    assert planned(longest)._python_steps is None
    monkeypatch.delitem(sys.modules, "numba")  # a process without it (the kernels here are loaded: nothing imports it)
    for stop, python_steps in [(None, None), (longest * 1.01, None), (longest, SlowPlant.python_steps)]:
        slave = planned(stop)
        assert slave._python_steps == python_steps, stop
    for k in range(SlowPlant.python_steps + 1):
        assert slave._python_steps == SlowPlant.python_steps - k
        slave.do_step(k * STEP / 4, STEP / 4)  # steps 4x smaller: the run outlasts the declared time, not the count
    assert slave._python_steps is None


@pytest.mark.slow  # a Python of its own
def test_a_short_run_of_the_slow_plant_never_imports_numba():
    """What the Python kernels are for: a host's 10 ms check of the FMU pays no 1.2 s of numba (models/jit.py)."""
    code = ("import sys; from nfal.fmus.slow_plant import SlowPlant; s = SlowPlant(instance_name='p'); "
            "s.setup_experiment(0.0, 0.01); s.exit_initialization_mode(); s.excitation_amplitude = 3e-6; "
            "[s.do_step(k * 5e-4, 5e-4) for k in range(20)]; print(s.height > 60e-6, 'numba' in sys.modules)")
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split() == \
        ["True", "False"]


def test_slow_plant_fmu_trajectory_equals_fixed_step_plant(slow):
    """Through fmpy's FMU2Slave, a frequency change included (sigma scales with f): equal to 1e-15 m."""
    frequencies = [RIG.frequency] * 30 + [RIG.frequency * 1.002] * 30
    slow.initialize()
    out = []
    for a, f in zip(EXCITATIONS, frequencies):
        slow.set(excitation_amplitude=a, drive_frequency=f)
        slow.step(STEP)
        out.append(slow.get("height", "velocity"))
    np.testing.assert_allclose(np.array(out), reference_slow(EXCITATIONS, frequencies), rtol=0, atol=1e-15)
    assert not slow.get("resting")


def test_slow_plant_frequency_rebuild_threshold():
    slave = SlowPlant(instance_name="slow")
    slave.setup_experiment(0.0)
    slave.exit_initialization_mode()
    plant = slave._plant
    slave.drive_frequency = RIG.frequency * (1 + 5e-10)
    slave.do_step(0.0, STEP)
    assert slave._plant is plant  # within 1e-9 relative: kept
    slave.drive_frequency = RIG.frequency * (1 + 2e-9)
    slave.do_step(STEP, STEP)
    assert slave._plant is not plant and slave._plant.plant.rig.frequency == slave.drive_frequency


def test_slow_plant_lifts_off_from_rest():
    """At rest on the surface, an |a| whose film force beats gravity lifts the object at the step start."""
    slave = SlowPlant(instance_name="slow")
    slave.initial_height = 5e-6
    slave.setup_experiment(0.0)
    slave.exit_initialization_mode()
    assert slave.resting
    slave.do_step(0.0, STEP)  # |a| = 0: stays
    assert slave.resting and slave.height == 5e-6
    slave.excitation_amplitude = 3e-6
    for k in range(1, 6):
        slave.do_step(k * STEP, STEP)
    assert not slave.resting and slave.height > 5e-6 and slave.velocity > 0


def test_slow_plant_reads_a_calibration_file(slow, tmp_path):
    """calibration = a JSON path: the same K as 'paper' gives the same trajectory."""
    path = tmp_path / "calibration.json"
    paper_calibration().save(path)
    slow.initialize(calibration=str(path))
    out = []
    for a in EXCITATIONS[:10]:
        slow.set(excitation_amplitude=a)
        slow.step(STEP)
        out.append(slow.get("height", "velocity"))
    np.testing.assert_allclose(np.array(out), reference_slow(EXCITATIONS[:10]), rtol=0, atol=1e-15)


def test_slow_plant_perturbation_calibration():
    slave = SlowPlant(instance_name="slow")
    slave.calibration = "perturbation"
    slave.setup_experiment(0.0)
    slave.exit_initialization_mode()
    assert "perturbation" in slave._calibration.name
    slave.excitation_amplitude = 2.2e-6
    slave.do_step(0.0, STEP)
    assert math.isfinite(slave.height)


def test_slow_plant_simulates_with_fmpy(fmus):
    result = fmpy.simulate_fmu(str(fmus["SlowPlant"][0]), stop_time=0.01, step_size=STEP, output_interval=STEP,
                               start_values={"excitation_amplitude": 2.2e-6})
    assert result["time"][-1] == pytest.approx(0.01)
    np.testing.assert_allclose(result["height"][1:], reference_slow([2.2e-6] * 20)[:, 0], rtol=0, atol=1e-15)


@pytest.mark.parametrize("name", ["SlowPlant", "ReynoldsPlant"])
def test_plant_fmus_validate(fmus, name):
    assert validate_fmu(str(fmus[name][0])) == []


@pytest.mark.parametrize("values, reason", [
    ({"mass": -0.1}, "mass = -0.1 is invalid"),
    ({"calibration": "no_such_file.json"}, "cannot read calibration no_such_file.json"),
    ({"initial_height": 1e-6}, "initial_height = 1e-06 is invalid"),
    ({"nominal_frequency": 0.0}, "nominal_frequency = 0.0 is invalid"),
])
def test_slow_plant_bad_parameter_is_an_error(slow, values, reason):
    with pytest.raises(FMICallException) as raised:
        slow.initialize(**values)
    assert raised.value.status == FMI_ERROR
    assert any(reason in message for message in slow.errors()), slow.messages


def test_slow_plant_negative_excitation_is_an_error(slow):
    slow.initialize()
    slow.set(excitation_amplitude=-1e-6)
    with pytest.raises(FMICallException):
        slow.step(STEP)
    assert any("excitation_amplitude = -1e-06 is invalid" in message for message in slow.errors())


def test_slow_plant_state_round_trip(slow):
    slow.initialize()
    for a in EXCITATIONS[:10]:
        slow.set(excitation_amplitude=a)
        slow.step(STEP)
    saved = slow.fmu.getFMUstate()
    serialized = slow.fmu.serializeFMUstate(saved)
    time = slow.time

    def continuation():
        out = []
        for a in EXCITATIONS[10:30]:
            slow.set(excitation_amplitude=a, drive_frequency=RIG.frequency * 1.001)
            slow.step(STEP)
            out.append(slow.get("height", "velocity", "resting"))
        return out

    first = continuation()
    slow.fmu.setFMUstate(saved)
    slow.time = time
    assert continuation() == first
    slow.fmu.setFMUstate(slow.fmu.deSerializeFMUstate(serialized))
    slow.time = time
    assert continuation() == first
    slow.fmu.freeFMUstate(saved)


# --- ReynoldsPlant ----------------------------------------------------------------------------------------
def test_reynolds_plant_steps_like_coupled_model(reynolds, coupled):
    levels = [7e-6, 6.5e-6, 7.5e-6, 7e-6]
    reynolds.initialize(initial_height=80e-6, excitation_amplitude=levels[0], envelope_following=False,
                        film_solver="time_marching")
    state = coupled.initial_state(80e-6, 0.0, levels[0])
    for level in levels:
        reynolds.set(excitation_amplitude=level)
        reynolds.step(STEP)
        state = coupled.advance(state, level, STEP)
        assert reynolds.get("height", "velocity", "oscillation_amplitude", "resting") == \
            (state.height, state.velocity, state.oscillation, False)


@pytest.mark.parametrize("solver", ["time_marching", "harmonic_balance"])
def test_reynolds_plant_lands_when_the_gap_closes_and_lifts_off_again(solver):
    slave = ReynoldsPlant(instance_name="full")
    slave.film_solver = solver
    slave.initial_height = 12e-6
    slave.setup_experiment(0.0)
    slave.exit_initialization_mode()
    slave.excitation_amplitude = 10e-6  # the surface's excursion reaches the object at once
    slave.do_step(0.0, STEP)
    assert slave.resting and slave.height == slave.rest_gap and slave.velocity == 0.0
    slave.excitation_amplitude = 0.0
    slave.do_step(STEP, STEP)
    assert slave.resting
    slave.excitation_amplitude = 3e-6  # eq. (12) with eq. (17) beats gravity at the rest gap
    slave.do_step(2 * STEP, STEP)
    assert not slave.resting and slave.height > 3e-6


def test_reynolds_plant_follows_the_drive_frequency():
    slave = ReynoldsPlant(instance_name="full")
    slave.film_solver = "time_marching"
    slave.excitation_amplitude = 7e-6
    slave.setup_experiment(0.0)
    slave.exit_initialization_mode()
    slave.do_step(0.0, STEP)
    slave.drive_frequency = RIG.frequency * 1.01
    slave.do_step(STEP, STEP)
    film = slave._film
    assert isinstance(film, TimeMarchingFilm)
    assert film.internal_state()["frequency"] == slave.drive_frequency
    assert film.internal_state()["time_s"] == pytest.approx(2 * STEP)


#: (|a| [m], drive frequency factor) per step: free flight, a new drive frequency, a touchdown, resting, a lift-off.
CORE_SCENARIO = [(5e-6, 1.0)] * 40 + [(5.5e-6, 1.01)] * 40 + [(60e-6, 1.01)] * 2 + [(0.0, 1.01)] * 3 + \
    [(3e-6, 1.01)] * 60


def test_the_reynolds_plants_compiled_core_steps_as_its_python(reynolds):
    """models/plant_core.py: the runtime steps the FMU's free flight with the compiled core (the slave's Python
    do_step is not called), and every output is the Python slave's to the bit, through a new drive frequency, a
    touchdown, resting and a lift-off, and across an FMU state saved and restored."""
    python = ReynoldsPlant(instance_name="python")
    python.initial_height = 80e-6
    python.setup_experiment(0.0)
    python.exit_initialization_mode()
    reynolds.initialize(initial_height=80e-6)
    calls = python_do_steps("ReynoldsPlant")
    names = ("height", "velocity", "resting", "oscillation_amplitude")
    saved, rested = None, []
    for k, (level, factor) in enumerate(CORE_SCENARIO):
        reynolds.set(excitation_amplitude=level, drive_frequency=RIG.frequency * factor)
        python.excitation_amplitude, python.drive_frequency = level, RIG.frequency * factor
        reynolds.step(STEP)
        python.do_step(k * STEP, STEP)
        assert reynolds.get(*names) == tuple(getattr(python, name) for name in names), k
        rested.append(python.resting)
        if k == 30:
            saved, state, at = reynolds.fmu.getFMUstate(), python._get_fmu_state(), reynolds.time
    assert 0 < len(calls) < len(CORE_SCENARIO) // 3, len(calls)  # the core took the free flight
    assert any(rested) and not rested[-1]  # landed, and lifted off again
    reynolds.fmu.setFMUstate(saved)
    python._set_fmu_state(state)
    reynolds.time = at
    for k in range(5):
        reynolds.set(excitation_amplitude=5e-6, drive_frequency=RIG.frequency)
        python.excitation_amplitude, python.drive_frequency = 5e-6, RIG.frequency
        reynolds.step(STEP)
        python.do_step(at + k * STEP, STEP)
        assert reynolds.get(*names) == tuple(getattr(python, name) for name in names)
    reynolds.fmu.freeFMUstate(saved)


@pytest.mark.parametrize("name, value, reason", [
    ("excitation_amplitude", 1e-2, "excitation_amplitude = 0.01 is invalid: must be at most"),
    ("excitation_amplitude", -1e-6, "excitation_amplitude = -1e-06 is invalid"),
    ("drive_frequency", 0.0, "drive_frequency = 0.0 is invalid")])
def test_the_compiled_core_leaves_a_refused_input_to_the_slave(reynolds, name, value, reason):
    """A finite input the slave refuses reaches the runtime's cache (only non-finite ones are refused at the set):
    the core declines the step, and the slave's Python says why, one logged error, the state kept."""
    reynolds.initialize(initial_height=80e-6, excitation_amplitude=5e-6)
    for _ in range(5):
        reynolds.step(STEP)  # the core's
    before = reynolds.get("height", "velocity")
    reynolds.set(**{name: value})
    with pytest.raises(FMICallException) as raised:
        reynolds.step(STEP)
    assert (raised.value.function, raised.value.status) == ("fmi2DoStep", FMI_ERROR)
    (error,) = reynolds.errors()
    assert reason in error and reynolds.get("height", "velocity") == before


def test_reynolds_plant_state_round_trip(reynolds):
    reynolds.initialize(excitation_amplitude=7e-6)
    reynolds.step(STEP)
    saved = reynolds.fmu.serializeFMUstate(reynolds.fmu.getFMUstate())
    time = reynolds.time
    reynolds.set(excitation_amplitude=6e-6)
    reynolds.step(STEP)
    first = reynolds.get("height", "velocity", "oscillation_amplitude")
    reynolds.fmu.setFMUstate(reynolds.fmu.deSerializeFMUstate(saved))
    reynolds.time = time
    reynolds.set(excitation_amplitude=6e-6)
    reynolds.step(STEP)
    assert reynolds.get("height", "velocity", "oscillation_amplitude") == first


def test_reynolds_plant_harmonic_balance_steps_like_the_averaged_plant():
    """The default film solver: the slow state stepped by FixedStepPlant over AveragedFilmPlant, the
    drive frequency followed (sigma scales with it, eq. 2)."""
    slave = ReynoldsPlant(instance_name="averaged")
    slave.initial_height, slave.excitation_amplitude = 80e-6, 7e-6
    slave.setup_experiment(0.0)
    slave.exit_initialization_mode()
    plant = FixedStepPlant(AveragedFilmPlant(RIG, slave._film.table))
    state = PlantState(80e-6)
    for level, frequency in ((7e-6, RIG.frequency), (6.5e-6, RIG.frequency * 1.01)):
        slave.excitation_amplitude, slave.drive_frequency = level, frequency
        slave.do_step(0.0, STEP)
        if frequency != RIG.frequency:
            plant = FixedStepPlant(AveragedFilmPlant(RIG.replace(frequency=frequency), slave._film.table))
        state = plant.advance(state, level, STEP)
        assert (slave.height, slave.velocity, slave.resting) == (state.height, state.velocity, False)
        assert slave.oscillation_amplitude == plant.plant.oscillation(state.height, level) > 0


@pytest.mark.parametrize("values, reason", [({"radial_nodes": 3}, "radial_nodes = 3"),
                                            ({"film_solver": "euler"}, "film_solver = 'euler'"),
                                            ({"harmonics": 0}, "harmonics = 0"),
                                            ({"shape": "no-such-shape"}, "shape = 'no-such-shape'")])
def test_reynolds_plant_bad_parameter_is_an_error(reynolds, values, reason):
    with pytest.raises(FMICallException):
        reynolds.initialize(**values)
    assert any(reason in message for message in reynolds.errors()), reynolds.messages


def test_reynolds_plant_simulates_with_fmpy(fmus):
    result = fmpy.simulate_fmu(str(fmus["ReynoldsPlant"][0]), stop_time=2e-3, step_size=STEP, output_interval=STEP,
                               start_values={"excitation_amplitude": 7e-6})
    assert np.all(np.isfinite(result["height"])) and result["oscillation_amplitude"][-1] > 0


def test_the_plants_core_leaves_the_steps_of_a_state_from_before_initialisation_to_the_slave(reynolds):
    """An FMU state taken before initialisation ended (its provisional set-up read: a state the core could step),
    restored after the core stepped free flight: the slave's doStep refuses the step, as its Python does."""
    assert refuses_a_state_from_before_initialisation(reynolds, STEP, "height", initial_height=80e-6,
                                                      excitation_amplitude=5e-6)
