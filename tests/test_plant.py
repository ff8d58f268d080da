import numpy as np
import pytest

from nfal.models.calibration import paper_calibration
from nfal.models.errors import InvalidParameterError
from nfal.models.plant import PlantState, SimplifiedPlant
from nfal.models.rig import RigParameters


@pytest.fixture(scope="module")
def plant():
    return SimplifiedPlant(RigParameters(), paper_calibration())


@pytest.mark.parametrize("height", [50e-6, 100e-6, 150e-6, 200e-6])
def test_equilibrium_satisfies_eq16(plant, height):
    rig = plant.rig
    a = plant.equilibrium_excitation(height)
    u, H = a / rig.reference_clearance, height / rig.reference_clearance
    K = plant.calibration(rig.squeeze_number(height))
    assert rig.stiffness_coefficient * u**2 * K == pytest.approx(rig.gravity_term * H**2, rel=1e-12)  # eq. (16)
    assert plant.equilibrium_height(a) == pytest.approx(height, rel=1e-9)


def test_dimensional_and_nondimensional_eq13_agree(plant):
    rig = plant.rig
    h, v, a = 120e-6, 3e-4, 3e-6
    accel = plant.acceleration(h, v, a)
    scale = rig.reference_clearance
    nondim = plant.rhs_nondimensional(0.0, [h / scale, v / (scale * rig.omega)], a / scale)[1]
    assert accel == pytest.approx(nondim * scale * rig.omega**2, rel=1e-12)


def test_release_settles_at_equilibrium(plant):
    a = plant.equilibrium_excitation(100e-6)
    path = plant.simulate(0.3, a, 80e-6, samples=301)
    assert path.height[-1] == pytest.approx(100e-6, rel=1e-5)
    assert path.height[0] == 80e-6 and not path.resting.any()


def test_advance_matches_simulate(plant):
    a = plant.equilibrium_excitation(140e-6)
    state = PlantState(100e-6)
    for _ in range(40):
        state = plant.advance(state, a, 1e-3)
    path = plant.simulate(0.04, a, 100e-6, samples=41)
    assert state.height == pytest.approx(path.height[-1], rel=1e-6)
    assert state.velocity == pytest.approx(path.velocity[-1], rel=1e-4, abs=1e-9)


def test_touchdown_rest_and_lift_off():
    heavy = SimplifiedPlant(RigParameters(mass=2.0), paper_calibration(), rest_gap=20e-6)
    lift = 2.0 * heavy.equilibrium_excitation(60e-6)

    def excitation(t):
        return 0.0 if 0.02 <= t < 0.4 else lift

    path = heavy.simulate(0.6, excitation, 60e-6, samples=601)
    assert np.all(np.isfinite(path.height)) and np.all(path.height >= 20e-6)
    assert path.resting.any(), "the object should have landed"
    landed = np.flatnonzero(path.resting)
    assert path.time[landed[0]] < 0.4 and np.all(path.velocity[path.resting] == 0.0)
    assert path.time[landed[-1]] <= 0.401, "lift-off when the force returns"
    assert path.height[-1] > 30e-6


def test_rest_persists_without_force():
    plant = SimplifiedPlant(RigParameters(), paper_calibration())
    state = plant.advance(PlantState(plant.rest_gap, 0.0, resting=True), 0.0, 1e-3)
    assert state.resting and state.height == plant.rest_gap and state.velocity == 0.0


@pytest.mark.parametrize("kwargs, name", [
    ({"excitation": -1e-6}, "excitation"), ({"excitation": np.nan}, "excitation"), ({"step": 0.0}, "step"),
])
def test_advance_rejects_bad_input(plant, kwargs, name):
    args = {"state": PlantState(100e-6), "excitation": 1e-6, "step": 1e-3} | kwargs
    with pytest.raises(InvalidParameterError, match=name):
        plant.advance(**args)


def test_rejects_state_below_rest_gap(plant):
    with pytest.raises(InvalidParameterError, match="height"):
        plant.advance(PlantState(1e-6), 1e-6, 1e-3)


def test_equilibrium_out_of_calibrated_range(plant):
    with pytest.raises(InvalidParameterError, match="calibrated range"):
        plant.equilibrium_height(1e-3)
