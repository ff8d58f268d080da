import numpy as np
import pytest

from nfal.errors import DataFormatError, InvalidParameterError
from nfal.models.calibration import (PAPER_COEFFICIENTS, PolynomialK, TabulatedK, load_calibration, paper_calibration,
                                     perturbation_calibration)
from nfal.models.excitation import PistonShape
from nfal.models.perturbation import piston_K_exact


def test_paper_eq17_values():
    K = paper_calibration()
    sigma = 100.0
    expected = sum(c * sigma**k for k, c in enumerate(PAPER_COEFFICIENTS))
    assert K(sigma) == pytest.approx(expected, rel=1e-14)
    assert K(100.0) == pytest.approx(1.2348 + 2.2928 - 1.301 + 0.29826 - 0.024985, rel=1e-12)


@pytest.mark.parametrize("calibration", [paper_calibration(), perturbation_calibration(PistonShape(), (1, 1e4), 120)],
                         ids=repr)
def test_derivative_is_exact(calibration):
    sigma = np.array([20.0, 80.0, 300.0])
    numeric = (calibration(sigma * (1 + 1e-6)) - calibration(sigma * (1 - 1e-6))) / (2e-6 * sigma)
    np.testing.assert_allclose(calibration.derivative(sigma), numeric, rtol=1e-6)


@pytest.mark.parametrize("calibration", [paper_calibration(), perturbation_calibration(PistonShape(), (1, 1e4), 120)],
                         ids=repr)
def test_the_scalar_path_equals_the_array_path(calibration):
    """The plants' inner loops call ``scalar`` (plain floats; scipy's spline call was 9x the slow plant's tick with a
    tabulated K); it must be the same function, held outside the range, to rounding."""
    sigma = np.concatenate([np.geomspace(0.1, 1e5, 3001), calibration.sigma_range])
    fast = np.array([calibration.scalar(float(x)) for x in sigma])
    np.testing.assert_allclose(fast, calibration(sigma), rtol=1e-13, atol=0.0)


def test_values_are_held_outside_the_range():
    K = paper_calibration()
    assert K(1e4) == K(500.0) and K(1.0) == K(10.0)
    assert K.derivative(1e4) == 0.0
    assert not K.in_range(1e4) and K.in_range(100.0)


def test_perturbation_table_interpolates_the_exact_piston():
    table = perturbation_calibration(PistonShape(), (1.0, 1e4), points=150, nodes=801)
    sigma = np.geomspace(1.3, 9e3, 37)
    np.testing.assert_allclose(table(sigma), piston_K_exact(sigma), rtol=2e-4)


@pytest.mark.parametrize("calibration", [paper_calibration(), TabulatedK([1, 2, 3, 4], [0.1, 0.4, 0.6, 0.7], name="t")],
                         ids=repr)
def test_save_and_load_round_trip(tmp_path, calibration):
    path = tmp_path / "k.json"
    calibration.save(path)
    again = load_calibration(path)
    sigma = np.linspace(*calibration.sigma_range, 9)
    np.testing.assert_array_equal(again(sigma), calibration(sigma))
    assert again.sigma_range == calibration.sigma_range


@pytest.mark.parametrize("content", ["not json", '{"kind": "spline"}', '{"kind": "polynomial"}'])
def test_load_rejects_garbage(tmp_path, content):
    path = tmp_path / "k.json"
    path.write_text(content)
    with pytest.raises(DataFormatError):
        load_calibration(path)


@pytest.mark.parametrize("sigma_range", [(0, 10), (10, 5), (1, np.inf)])
def test_bad_range(sigma_range):
    with pytest.raises(InvalidParameterError, match="sigma_range"):
        PolynomialK([1.0], sigma_range)


def test_table_needs_increasing_sigma():
    with pytest.raises(DataFormatError, match="increase"):
        TabulatedK([1, 3, 2, 4], [1, 1, 1, 1])
