"""The compiled 2 kHz path (firmware/loop/): its law equals DiscreteControlLaw to the bit."""

import numpy as np
import pytest

from nfal.apps.compiled_loop import CompiledLaw
from nfal.errors import InvalidParameterError
from nfal.models.control_law import LIFT_OFF_TIME_S, DiscreteControlLaw
from nfal.models.calibration import paper_calibration
from nfal.models.pid_design import DesignSpec, design_schedule, fixed_design
from nfal.models.plant import SimplifiedPlant
from nfal.models.rig import RigParameters
from nfal.models.table2 import REFERENCE_ZERO_RATIO
from nfal.models.transducer import Transducer

SAMPLED = design_schedule(None, spec=DesignSpec(sample_rate_hz=2000.0, reference_zero=REFERENCE_ZERO_RATIO))
LAWS = {
    "the paper's law": DiscreteControlLaw(design_schedule()),
    "the Controller FMU's": DiscreteControlLaw(SAMPLED, lift_off_time_s=LIFT_OFF_TIME_S,
                                               actuator_lag_s=Transducer().time_constant_s(),
                                               reference_zero_ratio=REFERENCE_ZERO_RATIO),
    "reference pair, tracking time": DiscreteControlLaw(SAMPLED, reference_filter_s=0.01, tracking_time_s=2e-3,
                                                        lift_off_time_s=0.04, max_excitation_m=6e-6),
    "linear at 80 um": DiscreteControlLaw(fixed_design(80e-6), reference_zero_ratio=1.0, actuator_lag_s=5e-3),
}


def _trajectory(seed: int, n: int = 4000):
    """References on a staircase, measurements a random walk from rest (5 um) with jumps, across the whole
    schedule and beyond it."""
    rng = np.random.default_rng(seed)
    references = np.repeat(rng.uniform(50e-6, 200e-6, n // 400 + 1), 400)[:n]
    measured = np.clip(5e-6 + np.cumsum(rng.normal(0.0, 2e-6, n)) + rng.choice([0.0, 40e-6], n, p=[0.99, 0.01]),
                       0.0, 1e-3)
    return references, measured


@pytest.mark.parametrize("name", LAWS)
def test_the_compiled_law_is_the_python_law_to_the_bit(name):
    law = LAWS[name]
    compiled = CompiledLaw(law)
    for seed in range(3):
        python = c = law.initial_state(120e-6, 3e-6)
        for reference, measured in zip(*_trajectory(seed)):
            expected, python = law.step(python, reference, measured)
            command, c = compiled.step(c, reference, measured)
            assert (command, c) == (expected, python)


def test_it_lifts_off_saturates_and_leads_on_the_way():
    """The trajectories reach what the law can do: lift-off, saturation, the lead's clamp (else the test is weak)."""
    law = LAWS["the Controller FMU's"]
    compiled, state, seen = CompiledLaw(law), law.initial_state(120e-6, 3e-6), set()
    for reference, measured in zip(*_trajectory(0)):
        command, state = compiled.step(state, reference, measured)
        seen |= {"lifting"} if state.lifting else set()
        seen |= {"saturated"} if command == law.max_excitation_m else set()
        seen |= {"off"} if command == 0.0 else set()
    assert seen == {"lifting", "saturated", "off"}


def test_an_input_out_of_range_raises_as_the_python_law_does():
    law = LAWS["the paper's law"]
    compiled, state = CompiledLaw(law), law.initial_state(120e-6, 3e-6)
    for reference, measured in ((300e-6, 100e-6), (100e-6, -1e-6), (100e-6, float("nan")), (float("inf"), 1e-4)):
        with pytest.raises(InvalidParameterError):
            compiled.step(state, reference, measured)


def test_a_law_with_a_feedforward_path_is_refused_by_name():
    plant = SimplifiedPlant(RigParameters(), paper_calibration())
    law = DiscreteControlLaw(SAMPLED, reference_filter_s=0.01, feedforward=plant)
    with pytest.raises(InvalidParameterError, match="feedforward"):
        CompiledLaw(law)
