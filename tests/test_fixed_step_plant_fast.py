"""FixedStepPlant's fast near-surface integrator (near_surface="fast") against the exact event-handling one."""

import pytest

from nfal.errors import InvalidParameterError
from nfal.models.calibration import paper_calibration
from nfal.models.fixed_step_plant import FixedStepPlant
from nfal.models.plant import ExcessDamping, PlantState, SimplifiedPlant
from nfal.models.rig import RigParameters

STEP = 5e-4
#: Stated tolerance: the fast path follows the exact one within this fraction of the clearance.
RELATIVE_TOLERANCE = 0.01


def _pair(excess):
    plant = SimplifiedPlant(RigParameters(), paper_calibration(), excess_damping=excess)
    return plant, FixedStepPlant(plant), FixedStepPlant(plant, near_surface="fast")


@pytest.mark.slow  # the exact near-surface path: ~4 ms a step
@pytest.mark.parametrize("excess", [None, ExcessDamping.rig_like()], ids=["eq6", "rig-like"])
@pytest.mark.parametrize("hold_height", [60e-6, 120e-6])
def test_lift_off_from_rest_follows_the_exact_path(excess, hold_height):
    """From rest under 1.2 x the |a| that holds hold_height: 0.15 s of lift-off, every step within 1 %
    (measured: at most 0.29 %)."""
    plant, exact, fast = _pair(excess)
    excitation = float(plant.equilibrium_excitation(hold_height)) * 1.2
    a = b = PlantState(plant.rest_gap, 0.0, True)
    worst = 0.0
    for _ in range(300):
        a, b = exact.advance(a, excitation, STEP), fast.advance(b, excitation, STEP)
        worst = max(worst, abs(a.height - b.height) / a.height)
    assert a.height > 2 * plant.rest_gap  # it has lifted off
    assert worst < RELATIVE_TOLERANCE


@pytest.mark.slow  # the exact near-surface path: ~4 ms a step
@pytest.mark.parametrize("start", [12e-6, 30e-6])
def test_a_fall_with_the_drive_off_follows_the_exact_path(start):
    """With the drive off the object sinks towards the surface (the film's damping ~ 1/h^3 slows it)."""
    plant, exact, fast = _pair(ExcessDamping.rig_like())
    a = b = PlantState(start, 0.0, False)
    for _ in range(300):
        a, b = exact.advance(a, 0.0, STEP), fast.advance(b, 0.0, STEP)
        assert abs(a.height - b.height) <= RELATIVE_TOLERANCE * a.height
    assert a.height < start


def test_touchdown_rests_at_the_rest_gap():
    """A sub-step that would pass the rest gap lands the object there, at rest."""
    plant, _, fast = _pair(None)
    landed = fast.advance(PlantState(plant.rest_gap + 1e-12, -0.05, False), 0.0, STEP)  # 1.5 nm of travel left
    assert landed == PlantState(plant.rest_gap, 0.0, True)


def test_resting_without_lift_off_is_a_no_op():
    plant, exact, fast = _pair(None)
    rest = PlantState(plant.rest_gap, 0.0, True)
    assert exact.advance(rest, 0.0, STEP) == fast.advance(rest, 0.0, STEP) == rest


def test_free_flight_is_unchanged_by_the_choice():
    """Away from the surface both choices run the same RK4: identical states."""
    plant, exact, fast = _pair(ExcessDamping.rig_like())
    state = PlantState(100e-6, 1e-4, False)
    excitation = float(plant.equilibrium_excitation(100e-6))
    assert exact.advance(state, excitation, STEP) == fast.advance(state, excitation, STEP)


def test_unknown_choice_is_refused():
    plant, _, _ = _pair(None)
    with pytest.raises(InvalidParameterError, match="near_surface"):
        FixedStepPlant(plant, near_surface="quick")
