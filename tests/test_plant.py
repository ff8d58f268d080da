import dataclasses

import numpy as np
import pytest
from scipy import integrate

from nfal.errors import InvalidParameterError
from nfal.models.calibration import paper_calibration
from nfal.models.plant import LIFT_OFF_MARGIN, PlantState, SimplifiedPlant
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


# --- the surface: rest and lift-off decided at the start of a step ---------------------------------------
SURFACES = {  # rig, rest gap [m]: the default pair, and a heavy object on a rougher surface
    "default": (RigParameters(), 5e-6),
    "heavy": (RigParameters(mass=2.0), 20e-6),
}


@pytest.fixture(scope="module", params=sorted(SURFACES))
def surface_plant(request):
    rig, rest_gap = SURFACES[request.param]
    return SimplifiedPlant(rig, paper_calibration(), rest_gap=rest_gap)


def free_release_from_rest_gap(plant, excitation, step):
    """Eq. (13) integrated without any surface logic from (rest_gap, 0): the reference for a lift-off. Its rise is
    within 2e-10 (relative) of that at rtol = 1e-12, atol = 1e-17 m in every case here (which made this module
    take 20.6 s rather than 6); the tests compare to 1e-3."""
    solution = integrate.solve_ivp(lambda t, y: [y[1], plant.acceleration(y[0], y[1], excitation)], (0.0, step),
                                   [plant.rest_gap, 0.0], method="Radau", rtol=1e-9, atol=(1e-15, 1e-12))
    assert solution.success
    return solution.y[0, -1]


@pytest.mark.parametrize("step", [5e-4, 1e-3])
@pytest.mark.parametrize("factor", [1.5, 2.0, 10.0])
@pytest.mark.parametrize("start", [
    PlantState(0.0, 0.0, resting=True),       # resting on the surface
    PlantState(0.0, 0.0, resting=False),      # released at the rest gap
    PlantState(0.0, -1e-6, resting=False),    # arriving at the rest gap, slowly
    PlantState(0.0, -1e-3, resting=False),    # arriving at the rest gap
], ids=["resting", "free-v0", "free-slow-down", "free-down"])
def test_lifting_excitation_at_rest_gap_leaves_the_surface(surface_plant, start, factor, step):
    """The film force at rest_gap beats gravity (|a| = factor x the rest-gap equilibrium amplitude): the
    object lands (inelastically) if it was moving down, then leaves at once; after the step it is free,
    above rest_gap, and where a free release from rest_gap at rest would be."""
    plant = surface_plant
    excitation = factor * plant.equilibrium_excitation(plant.rest_gap)
    state = plant.advance(dataclasses.replace(start, height=plant.rest_gap), excitation, step)
    expected = free_release_from_rest_gap(plant, excitation, step)
    assert not state.resting and state.velocity > 0
    assert state.height > plant.rest_gap
    assert state.height - plant.rest_gap == pytest.approx(expected - plant.rest_gap, rel=1e-3)


@pytest.mark.parametrize("factor", [0.0, 0.5, 0.99])
@pytest.mark.parametrize("velocity", [0.0, -1e-6, -1e-3, -0.1])
def test_release_at_rest_gap_without_lift_rests(surface_plant, velocity, factor):
    """Released (not resting) at rest_gap moving down or at rest, with a film force below the weight: it
    lands and rests there, without error."""
    plant = surface_plant
    excitation = factor * plant.equilibrium_excitation(plant.rest_gap)
    state = plant.advance(PlantState(plant.rest_gap, velocity, resting=False), excitation, 5e-4)
    assert state == PlantState(plant.rest_gap, 0.0, resting=True)


@pytest.mark.parametrize("factor", [1.0 - 1e-12, 1.0, 1.0 + 1e-12])
@pytest.mark.parametrize("start", [PlantState(0.0, 0.0, resting=True), PlantState(0.0, 0.0, resting=False),
                                   PlantState(0.0, -1e-3, resting=False)], ids=["resting", "free-v0", "free-down"])
def test_excitation_at_the_lift_off_threshold_does_not_chatter(surface_plant, start, factor):
    """|a| at the rest-gap equilibrium amplitude to the last bits: it either rests or creeps up, no error."""
    plant = surface_plant
    excitation = factor * plant.equilibrium_excitation(plant.rest_gap)
    state = plant.advance(dataclasses.replace(start, height=plant.rest_gap), excitation, 5e-4)
    if state.resting:
        assert state == PlantState(plant.rest_gap, 0.0, resting=True)
    else:
        assert 0 <= state.height - plant.rest_gap < 1e-15 and state.velocity >= 0


@pytest.mark.parametrize("slope", [0.1, 1.0, 100.0])
def test_ramp_through_the_lift_off_threshold(surface_plant, slope):
    """|a| ramps (slope per s, relative) through the rest-gap equilibrium amplitude: rests until then, free
    from the next sample on."""
    plant = surface_plant
    a0 = plant.equilibrium_excitation(plant.rest_gap)
    crossing = 0.1 / slope
    path = plant.simulate(3 * crossing, lambda t: a0 * (0.9 + slope * t), PlantState(plant.rest_gap, 0.0, resting=True),
                          samples=300)  # no sample on the crossing
    np.testing.assert_array_equal(path.resting, path.time <= crossing)
    assert np.all(np.diff(path.height[path.time > crossing]) > 0)


def test_the_rest_test_is_levitation_force_at_the_rest_gap_to_the_bit(surface_plant):
    """The rest test's film force (floats, K at rest_gap kept) is levitation_force's (numpy) to the last bit: a
    different rounding would move the lift-off threshold."""
    plant = surface_plant
    threshold = plant.equilibrium_excitation(plant.rest_gap)
    for excitation in [0.0, *threshold * (1.0 + np.linspace(-1e-9, 1e-9, 201)), *np.geomspace(1e-9, 1e-4, 200)]:
        expected = float(plant.levitation_force(plant.rest_gap, excitation) - (1.0 + LIFT_OFF_MARGIN) * plant.weight)
        assert plant._net_resting_force(0.0, lambda t: excitation) == expected, excitation


@pytest.mark.parametrize("state, factor, expected", [
    (PlantState(0.0, 0.0, resting=True), 0.5, True),
    (PlantState(0.0, 0.0, resting=True), 2.0, False),
    (PlantState(0.0, -1e-3, resting=False), 0.5, True),
    (PlantState(0.0, 1e-3, resting=False), 0.5, False),
    (PlantState(1e-6, -1e-3, resting=False), 0.5, False),
], ids=["resting", "resting-lifted", "landing", "rising", "above"])
def test_rests(plant, state, factor, expected):
    """On the surface (resting, or at rest_gap with v <= 0) and the film at rest_gap below the weight."""
    state = dataclasses.replace(state, height=plant.rest_gap + state.height)
    assert plant.rests(state, factor * plant.equilibrium_excitation(plant.rest_gap)) is expected
