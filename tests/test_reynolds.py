"""Time-marching K(sigma) of the fixed-object film (models/reynolds.py) against the perturbation route,
its own convergence orders, and the trapped-gas limit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nfal.errors import ConvergenceError, InvalidParameterError
from nfal.models.excitation import PistonShape, paper_shape
from nfal.models.perturbation import first_order_pressure, perturbation_K, radial_grid
from nfal.models.reynolds import discrete_mean_correction, periodic_film, time_marching_K

PISTON = PistonShape()
PAPER = paper_shape()
SHAPES = {"piston": PISTON, "paper": PAPER}


def trapped_gas_K_finite_delta(delta: float) -> float:
    """Piston, sigma -> inf, finite delta: P H = C in the interior; zero net rim flux over a period
    <H^3 (P^2 - 1)> = 0 gives C^2 <H> = <H^3>, i.e. C = sqrt(1 + 1.5 delta^2); the mean pressure is
    C <1/H> = C / sqrt(1 - delta^2), and K = (<P> - 1) / delta^2."""
    return (math.sqrt(1.0 + 1.5 * delta**2) / math.sqrt(1.0 - delta**2) - 1.0) / delta**2


class Negated:
    """-eps_hat: the same film as delta -> -delta (duck-typed shape)."""

    def __init__(self, shape):
        self.shape = shape

    def __call__(self, R):
        return -self.shape(R)

    def slope(self, R):
        return -self.shape.slope(R)


# --- agreement with the perturbation route ------------------------------------------------------
@pytest.mark.parametrize("delta", [0.01, 0.005])
@pytest.mark.parametrize("sigma", [5.0, 20.0, 50.0, 200.0, 500.0])
@pytest.mark.parametrize("shape_name", ["piston", "paper"])
def test_agrees_with_perturbation_K(shape_name, sigma, delta):
    """Same 101 nodes, 256 steps: |K_tm - K_pert| <= 4e-4 (K is O(1); the gap is the O(dT^2) time error,
    the O(dR^2) difference of two summations by parts, and the O(delta^2) physics)."""
    shape = SHAPES[shape_name]
    K_tm = time_marching_K(shape, sigma, delta=delta)[0]
    K_pert = perturbation_K(shape, sigma, 101)[0]
    assert abs(K_tm - K_pert) <= 4e-4


@pytest.mark.parametrize("sigma", [5.0, 50.0, 500.0])
@pytest.mark.parametrize("shape_name", ["piston", "paper"])
def test_finite_delta_correction_is_quadratic(shape_name, sigma):
    """K(delta) - K(0) = O(delta^2), not O(delta): delta -> -delta is T -> T + pi, so odd orders vanish.

    Halving delta divides successive differences by 4 (a linear term would give 2)."""
    K = {d: periodic_film(SHAPES[shape_name], sigma, delta=d, nodes=41, steps_per_period=64, tolerance=1e-11).K
         for d in (0.04, 0.02, 0.01)}
    ratio = (K[0.04] - K[0.02]) / (K[0.02] - K[0.01])
    assert 3.8 <= ratio <= 4.2


@pytest.mark.parametrize("sigma", [20.0, 200.0])
def test_force_is_even_in_delta(sigma):
    """Flipping the sign of the excitation (delta -> -delta) leaves K unchanged (to 1e-8)."""
    K_plus = periodic_film(PAPER, sigma, delta=0.05, nodes=41, steps_per_period=64, tolerance=1e-11).K
    K_minus = periodic_film(Negated(PAPER), sigma, delta=0.05, nodes=41, steps_per_period=64, tolerance=1e-11).K
    assert abs(K_plus - K_minus) <= 1e-8 * max(abs(K_plus), 1.0)


@pytest.mark.parametrize("sigma", [20.0, 200.0])
@pytest.mark.parametrize("shape_name", ["piston", "paper"])
def test_small_delta_limit_is_the_discrete_perturbation_problem(shape_name, sigma):
    """Richardson-extrapolated to delta -> 0 (delta^2) and dT -> 0 (dT^2), the time-marching K equals
    2 sum V_n Pi_5,n of the same finite volumes (Pi_5 from the flux balance) within 5e-6; unextrapolated
    the gap is up to 3e-4. For the piston that discrete formula is perturbation_K itself."""
    shape = SHAPES[shape_name]
    nodes = 41
    R, faces, volumes = radial_grid(nodes)
    _, amplitude = first_order_pressure(shape, sigma, nodes)
    K_discrete = 2.0 * np.sum(volumes * discrete_mean_correction(shape, amplitude, R, faces))

    def zero_delta(steps):
        K = [periodic_film(shape, sigma, delta=d, nodes=nodes, steps_per_period=steps, tolerance=1e-11).K
             for d in (0.02, 0.01)]
        return K[1] - (K[0] - K[1]) / 3.0

    coarse, fine = zero_delta(128), zero_delta(256)
    assert abs(fine + (fine - coarse) / 3.0 - K_discrete) <= 5e-6
    if shape_name == "piston":
        assert K_discrete == pytest.approx(perturbation_K(shape, sigma, nodes)[0], abs=1e-12)


# --- convergence orders -------------------------------------------------------------------------
def observed_order(coarse, medium, fine):
    return math.log2(abs(coarse - medium) / abs(medium - fine))


@pytest.mark.parametrize("sigma", [20.0, 200.0])
@pytest.mark.parametrize("shape_name", ["piston", "paper"])
def test_second_order_in_radius(shape_name, sigma):
    """Halving dR (41, 81, 161 nodes) at delta = 0.05: observed order in [1.8, 2.2]."""
    K = [periodic_film(SHAPES[shape_name], sigma, delta=0.05, nodes=n, steps_per_period=64, tolerance=1e-11).K
         for n in (41, 81, 161)]
    assert 1.8 <= observed_order(*K) <= 2.2


@pytest.mark.parametrize("sigma", [5.0, 50.0, 200.0, 500.0])
@pytest.mark.parametrize("shape_name", ["piston", "paper"])
def test_second_order_in_time(shape_name, sigma):
    """Doubling steps per period (64, 128, 256) at delta = 0.05: observed order in [1.8, 2.2] (BDF2)."""
    K = [periodic_film(SHAPES[shape_name], sigma, delta=0.05, nodes=41, steps_per_period=n, tolerance=1e-11).K
         for n in (64, 128, 256)]
    assert 1.8 <= observed_order(*K) <= 2.2


# --- trapped-gas limit ----------------------------------------------------------------------------
def test_trapped_gas_formula_small_delta_is_five_quarters():
    assert trapped_gas_K_finite_delta(1e-4) == pytest.approx(1.25, abs=1e-6)


@pytest.mark.parametrize("delta", [0.3, 0.5])
@pytest.mark.parametrize("sigma,nodes", [(500.0, 201), (2000.0, 201), (8000.0, 401)])
def test_piston_approaches_trapped_gas(sigma, nodes, delta):
    """K_trap(delta) - K(sigma, delta) lies in [1.5, 2.0] / sqrt(sigma): the rim boundary layer's
    correction (linear theory: (sqrt(2) + sqrt(2)/4) / sqrt(sigma) = 1.77 / sqrt(sigma)); and the
    finite-delta excess K(delta) - K(0.01) matches K_trap(delta) - 5/4 within 1 / sqrt(sigma) relative."""
    K = periodic_film(PISTON, sigma, delta=delta, nodes=nodes, steps_per_period=128).K
    K_small = periodic_film(PISTON, sigma, delta=0.01, nodes=nodes, steps_per_period=128).K
    K_trap = trapped_gas_K_finite_delta(delta)
    assert 1.5 / math.sqrt(sigma) <= K_trap - K <= 2.0 / math.sqrt(sigma)
    assert abs((K - K_small) / (K_trap - 1.25) - 1.0) <= 1.0 / math.sqrt(sigma)


# --- the periodic field ------------------------------------------------------------------------------
def test_periodic_field_first_harmonic_matches_perturbation():
    """The stored P(R, T) holds the rim at 1, averages back to K, and its first harmonic is
    delta Pi (eq. 10) within 2e-3 of max|Pi| delta (O(delta) + O(dT^2))."""
    sigma, delta = 50.0, 0.01
    film = periodic_film(PAPER, sigma, delta=delta)
    assert film.pressure.shape == (256, 101)
    np.testing.assert_array_equal(film.pressure[:, -1], 1.0)
    _, volumes = radial_grid(101)[1:]
    assert 2.0 * np.mean(film.pressure - 1.0, axis=0) @ volumes / delta**2 == pytest.approx(film.K, rel=1e-12)
    harmonic = 2.0 * np.mean((film.pressure - 1.0) * np.exp(-1j * film.time)[:, None], axis=0)
    _, amplitude = first_order_pressure(PAPER, sigma, 101)
    assert np.max(np.abs(harmonic - delta * amplitude)) <= 2e-3 * delta * np.max(np.abs(amplitude))


def test_extrapolation_gives_the_plain_marching_answer_faster():
    """At sigma = 500 the slowest film mode contracts by 0.93 per period: plain marching needs ~200
    periods, the reduced-rank extrapolation < 30, and both agree to the tolerance."""
    fast = periodic_film(PISTON, 500.0, nodes=41, steps_per_period=64, tolerance=1e-9)
    plain = periodic_film(PISTON, 500.0, nodes=41, steps_per_period=64, tolerance=1e-9, extrapolate=False)
    assert fast.periods < 30 < plain.periods
    assert fast.K == pytest.approx(plain.K, rel=2e-8)


def test_progress_is_reported_per_sigma():
    calls = []
    K = time_marching_K(PISTON, [5.0, 10.0, 20.0], nodes=21, steps_per_period=32,
                        progress=lambda d, t: calls.append((d, t)))
    assert K.shape == (3,)
    assert calls == [(1, 3), (2, 3), (3, 3)]


def test_not_converging_within_max_periods_raises():
    with pytest.raises(ConvergenceError, match="did not converge"):
        periodic_film(PISTON, 500.0, nodes=21, steps_per_period=32, max_periods=4)


# --- bad input ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("sigma", [0.0, -1.0, float("nan"), float("inf"), [5.0, -2.0]])
def test_bad_sigma(sigma):
    with pytest.raises(InvalidParameterError, match="sigma"):
        time_marching_K(PISTON, sigma)


@pytest.mark.parametrize("kwargs,name", [
    ({"delta": 0.0}, "delta"), ({"delta": 1.0}, "delta"), ({"delta": -0.1}, "delta"), ({"delta": "x"}, "delta"),
    ({"nodes": 4}, "nodes"), ({"nodes": 10.0}, "nodes"), ({"nodes": True}, "nodes"),
    ({"steps_per_period": 7}, "steps_per_period"), ({"steps_per_period": 16.5}, "steps_per_period"),
    ({"tolerance": 0.0}, "tolerance"), ({"max_periods": 2}, "max_periods"), ({"progress": 3}, "progress"),
])
def test_bad_settings(kwargs, name):
    with pytest.raises(InvalidParameterError, match=name):
        time_marching_K(PISTON, 10.0, **kwargs)


def test_delta_that_closes_the_gap_is_rejected():
    """The paper shape reaches eps_hat = 2.55 at the rim: delta = 0.5 would close the gap."""
    with pytest.raises(InvalidParameterError, match="gap"):
        periodic_film(PAPER, 10.0, delta=0.5)


def test_unknown_keyword_is_an_error():
    with pytest.raises(TypeError):
        time_marching_K(PISTON, 10.0, nodez=41)
