"""LPV coefficients of eq. (20): against a numerical linearisation of eq. (13), exact vs. central dK/dsigma."""

import numpy as np
import pytest

from nfal.errors import InvalidParameterError
from nfal.models.calibration import (PAPER_COEFFICIENTS, PolynomialK, TabulatedK, paper_calibration,
                                     perturbation_calibration)
from nfal.models.excitation import PistonShape
from nfal.models.lpv import calibration_slope, lpv_coefficients
from nfal.models.plant import SimplifiedPlant
from nfal.models.rig import RigParameters

RIG = RigParameters()


def _table_calibration():
    sigma = np.geomspace(10, 500, 40)
    return TabulatedK(sigma, paper_calibration()(sigma), name="eq. 17 tabulated")


@pytest.mark.parametrize("height", [50e-6, 80e-6, 120e-6, 160e-6, 200e-6])
def test_coefficients_match_numerical_linearisation_of_eq13(height):
    """Central differences of rhs_nondimensional (step 1e-6 relative) agree with eq. (20) to 1e-6."""
    K = paper_calibration()
    plant = SimplifiedPlant(RIG, K)
    lpv = lpv_coefficients(height, RIG, K)
    H, u = height / RIG.reference_clearance, float(lpv.excitation_m) / RIG.reference_clearance
    f = lambda H_, V_, u_: plant.rhs_nondimensional(0.0, [H_, V_], u_)[1]  # noqa: E731
    dH, dV, du = 1e-6 * H, 1e-8, 1e-6 * u
    assert abs(f(H, 0.0, u)) < 1e-12  # an equilibrium (eq. 16)
    assert -(f(H + dH, 0, u) - f(H - dH, 0, u)) / (2 * dH) == pytest.approx(float(lpv.alpha0), rel=1e-6)
    assert -(f(H, dV, u) - f(H, -dV, u)) / (2 * dV) == pytest.approx(float(lpv.alpha1), rel=1e-6)
    assert (f(H, 0, u + du) - f(H, 0, u - du)) / (2 * du) == pytest.approx(float(lpv.beta0), rel=1e-6)


@pytest.mark.parametrize("make", [paper_calibration, _table_calibration,
                                  lambda: perturbation_calibration(PistonShape(), (10.0, 600.0), points=40, nodes=101)],
                         ids=["polynomial", "table", "perturbation"])
def test_central_difference_scheme_matches_exact_derivative(make):
    """The stated scheme (relative step 1e-4) is within 1e-6 relative of the exact slope, for every K source."""
    K = make()
    heights = np.linspace(50e-6, 200e-6, 7)
    exact = lpv_coefficients(heights, RIG, K, derivative="exact")
    central = lpv_coefficients(heights, RIG, K, derivative="central")
    np.testing.assert_allclose(central.alpha0, exact.alpha0, rtol=1e-6)
    np.testing.assert_allclose(central.beta0, exact.beta0, rtol=0)
    sigma = RIG.squeeze_number(heights)
    np.testing.assert_allclose(calibration_slope(K, sigma, "central"), calibration_slope(K, sigma, "exact"),
                               rtol=1e-6, atol=1e-9)


def test_paper_rig_is_open_loop_stable_over_work_range():
    lpv = lpv_coefficients(np.linspace(50e-6, 200e-6, 31))
    assert np.all(lpv.alpha0 > 0) and np.all(lpv.alpha1 > 0) and np.all(lpv.beta0 > 0)


def test_si_transfer_function_has_rescaled_poles():
    lpv = lpv_coefficients(100e-6)
    si = np.sort(np.real(lpv.transfer_function("si").poles()))
    nd = np.sort(np.real(lpv.transfer_function("nondimensional").poles()))
    np.testing.assert_allclose(si, nd * RIG.omega, rtol=1e-9)
    assert lpv.damping_si == pytest.approx(RIG.squeeze_film_damping(100e-6) / RIG.mass, rel=1e-12)


@pytest.mark.parametrize("height", [np.nan, -1e-6, 0.0, 5e-6, 1e-3])
def test_bad_or_uncalibrated_heights_raise(height):
    with pytest.raises(InvalidParameterError):
        lpv_coefficients(height)


def test_heights_beyond_a_short_calibration_are_one_line_that_says_what_to_do():
    """A short identification's K covers a few heights: designing the work range over it says so in one line (it
    printed the 31 heights as a 6-line array)."""
    short = PolynomialK(PAPER_COEFFICIENTS, (100.0, 150.0), name="a short identification")
    with pytest.raises(InvalidParameterError) as caught:
        lpv_coefficients(np.linspace(50e-6, 200e-6, 31), RIG, short)
    assert str(caught.value) == (
        "design heights = 50.0–200.0 µm is invalid: must be within 80.0–98.0 µm, where a short identification is "
        "calibrated: design within it (nfal design --heights; the Controller's reference_min, reference_max), or "
        "calibrate over these heights (from a rig: a longer identification, nfal identify --equilibria spanning them)")


def test_unknown_derivative_scheme_raises():
    with pytest.raises(InvalidParameterError, match="derivative"):
        lpv_coefficients(100e-6, derivative="forward")
