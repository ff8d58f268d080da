"""The compiled kernels see the same K and damping as the Python objects they were built from (models/slow_kernels.py).

Every K (PolynomialK, TabulatedK, a FilmForceTable) and damping correction (ExcessDamping, DampingCorrection)
is carried into compiled code as data: each must evaluate as its object does, inside its range and held at
its ends outside it, to round-off (1e-12 relative). The kernels run as Python until compiled (models/jit.py), and
both give the same bits.
"""

import numpy as np
import pytest

from nfal.models import slow_kernels
from nfal.models.calibration import TabulatedK, paper_calibration, perturbation_calibration
from nfal.models.damping import DampingCorrection
from nfal.models.excitation import PistonShape
from nfal.models.film_force_table import FilmForceTable
from nfal.models.fixed_step_plant import FixedStepPlant, damping_correction
from nfal.models.plant import ExcessDamping, SimplifiedPlant
from nfal.models.rig import RigParameters

RIG = RigParameters()
slow_kernels.load()  # what these tests check is compiled code
HEIGHTS = np.array([50e-6, 75e-6, 100e-6, 130e-6, 160e-6, 200e-6])
CALIBRATIONS = {"polynomial": paper_calibration(),
                "table": TabulatedK([1, 2, 3, 4, 8], [0.1, 0.4, 0.6, 0.7, 0.72], name="t"),
                "perturbation": perturbation_calibration(PistonShape(), points=40)}
CORRECTIONS = {"none": None, "power": ExcessDamping.rig_like(),
               "table": DampingCorrection(HEIGHTS, np.array([1.0, 1.02, 1.2, 1.9, 3.5, 9.0]))}


@pytest.mark.parametrize("name", sorted(CALIBRATIONS))
def test_a_calibration_s_curve_is_the_calibration(name):
    calibration = CALIBRATIONS[name]
    low, high = calibration.sigma_range
    sigmas = np.concatenate([[0.5 * low, low, high, 2 * high], np.geomspace(low, high, 97)])
    compiled = [slow_kernels.curve_value(*calibration.curve(), sigma, 0.3) for sigma in sigmas]
    np.testing.assert_allclose(compiled, [calibration.scalar(s) for s in sigmas], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(compiled, calibration(sigmas), rtol=1e-12, atol=1e-15)


def test_a_film_table_s_curve_is_the_table():
    table = FilmForceTable(PistonShape(), 17, 4, sigma_range=(5.0, 500.0), sigmas=12, richardson=False)
    sigmas = np.geomspace(2.0, 1000.0, 41)
    for delta in (0.0, 0.5 * table.delta_max, 2.0 * table.delta_max):
        compiled = [slow_kernels.curve_value(*table.curve(), sigma, delta) for sigma in sigmas]
        np.testing.assert_allclose(compiled, table(sigmas, delta), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("name", sorted(CORRECTIONS))
def test_a_damping_correction_s_factor_is_the_correction(name):
    model = CORRECTIONS[name]
    heights = np.concatenate([[10e-6, 300e-6], np.linspace(40e-6, 220e-6, 91)])
    compiled = [slow_kernels.damping_factor(damping_correction(model), h) for h in heights]
    expected = np.ones_like(heights) if model is None else model.factor(heights)
    np.testing.assert_allclose(compiled, expected, rtol=1e-12)


@pytest.mark.parametrize("name", sorted(CORRECTIONS))
def test_the_compiled_acceleration_is_the_plant_s(name):
    plant = SimplifiedPlant(RIG, paper_calibration(), excess_damping=CORRECTIONS[name])
    fixed = FixedStepPlant(plant)
    for h, v, a in [(60e-6, 0.0, 1.6e-6), (120e-6, -2e-3, 3e-6), (190e-6, 4e-3, 6e-6)]:
        assert fixed.acceleration(h, v, a) == pytest.approx(float(plant.acceleration(h, v, a)), rel=1e-10, abs=1e-9)


@pytest.mark.parametrize("name", sorted(CORRECTIONS))
def test_python_and_compiled_kernels_give_the_same_bits(name):
    """A short run steps the kernels as Python (fmus/rig_contract.py): it must follow the compiled path to the bit,
    through free flight, the near-surface integrator and a landing."""
    plant = FixedStepPlant(SimplifiedPlant(RIG, perturbation_calibration(PistonShape(), points=40),
                                           excess_damping=CORRECTIONS[name]))
    model, rest = plant.model, plant.plant.rest_gap
    for h, v, a in [(60e-6, 0.0, 1.6e-6), (120e-6, -2e-3, 3e-6), (190e-6, 4e-3, 6e-6), (40e-6, -0.2, 0.5e-6)]:
        for kernel, args in [("free_flight", (h, v, a, 5e-4, 8, 3 * rest)),
                             ("exponential_advance", (h, v, a, 5e-4, rest)), ("substeps", (5e-4, h, 2 * h)),
                             ("acceleration", (h, v, a))]:
            compiled = getattr(slow_kernels, kernel)
            assert compiled.py_func(model, *args) == compiled(model, *args), (kernel, h, v, a)
    landing = (model, 1.2 * rest, 0.0, 0.0, 5e-3, 1.1999 * rest)  # a rest gap just below: reached in the step
    assert slow_kernels.exponential_advance.py_func(*landing) == slow_kernels.exponential_advance(*landing)
    assert slow_kernels.exponential_advance(*landing)[2]
