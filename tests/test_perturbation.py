import numpy as np
import pytest

from nfal.errors import InvalidParameterError
from nfal.models.excitation import PistonShape, PlateModeShape, paper_shape
from nfal.models.perturbation import perturbation_K, piston_K_exact, radial_grid, trapped_gas_K

SIGMAS = np.array([0.5, 5.0, 50.0, 500.0])


def test_control_volumes_tile_the_disc():
    _, _, volumes = radial_grid(41)
    assert volumes.sum() == pytest.approx(0.5, rel=1e-14)  # int_0^1 R dR


@pytest.mark.parametrize("sigma", [1e-3, 1e-2])
def test_exact_piston_small_sigma_limit(sigma):
    # sigma -> 0: K = 5 sigma^2 / 192 (gas escapes; derived in docs/physics.md)
    assert piston_K_exact(sigma)[0] == pytest.approx(5 * sigma**2 / 192, rel=2 * sigma)


def test_exact_piston_trapped_gas_limit():
    # sigma -> inf: 5/4 (Langlois), approached like 1/sqrt(sigma)
    gaps = 1.25 - piston_K_exact([1e4, 4e4, 1.6e5])
    assert gaps[-1] < 2e-2
    np.testing.assert_allclose(gaps[:-1] / gaps[1:], 2.0, rtol=0.02)


@pytest.mark.parametrize("sigma", SIGMAS)
def test_second_order_in_radial_nodes_against_exact_piston(sigma):
    exact = piston_K_exact(sigma)[0]
    errors = [abs(perturbation_K(PistonShape(), sigma, n)[0] - exact) for n in (101, 201, 401)]
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    np.testing.assert_allclose(orders, 2.0, atol=0.05)
    assert errors[-1] < 1e-4 * max(exact, 1e-3)


@pytest.mark.parametrize("shape", [PistonShape(), PlateModeShape(1), PlateModeShape(2), paper_shape()], ids=repr)
def test_trapped_gas_limit_for_any_shape(shape):
    # K(sigma) -> int R eps^2 dR + 3/4 eps(1)^2 with a 1/sqrt(sigma) boundary layer at the rim
    limit = trapped_gas_K(shape)
    gaps = limit - perturbation_K(shape, [2.5e4, 1e5], 3201)
    assert np.all(gaps > 0)
    assert gaps[0] / gaps[1] == pytest.approx(2.0, rel=0.06)


def test_tabulated_and_closed_form_piston_agree():
    # the standard route through a general shape equals the closed form at every sigma
    np.testing.assert_allclose(perturbation_K(PistonShape(), SIGMAS, 801), piston_K_exact(SIGMAS), rtol=1e-4, atol=1e-8)


def test_paper_shape_goes_negative_at_small_sigma():
    # Sec. 3.2: "at small squeeze numbers, the numerically obtained values of K become negative"
    K = perturbation_K(paper_shape(), [10.0, 30.0, 300.0])
    assert K[0] < 0 and K[1] < 0 and K[2] > 0


@pytest.mark.parametrize("bad", [0.0, -1.0, np.nan, np.inf, []])
def test_bad_sigma(bad):
    with pytest.raises(InvalidParameterError, match="sigma"):
        perturbation_K(PistonShape(), bad)


@pytest.mark.parametrize("bad", [3, 10.5, "100"])
def test_bad_nodes(bad):
    with pytest.raises(InvalidParameterError, match="nodes"):
        perturbation_K(PistonShape(), 10.0, bad)
