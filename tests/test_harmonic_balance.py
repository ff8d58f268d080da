"""The harmonic-balance film (models/harmonic_balance.py), its K(sigma, delta) table (models/film_force_table.py)
and the averaged plant (models/averaged_plant.py), against the time-marching reference."""

from __future__ import annotations

import numpy as np
import pytest

from nfal.errors import InvalidParameterError
from nfal.models.averaged_plant import AveragedFilmPlant
from nfal.models.coupled import CoupledModel
from nfal.models.excitation import TabulatedShape, largest_excursion, parse_shape
from nfal.models.film_force_table import FilmForceTable, cached_table
from nfal.models.harmonic_balance import HarmonicBalanceFilm, fourier_differentiation
from nfal.models.perturbation import first_order_pressure, perturbation_K, radial_grid
from nfal.models.reynolds import discrete_mean_correction, periodic_film
from nfal.models.rig import RigParameters

NODES = 41
SHAPES = {name: parse_shape(name) for name in ("paper", "piston", "plate:2")}


@pytest.fixture(scope="module")
def films():
    return {name: HarmonicBalanceFilm(shape, NODES, 6) for name, shape in SHAPES.items()}


def test_fourier_differentiation_is_exact_for_the_kept_harmonics():
    points = 13
    T = 2 * np.pi * np.arange(points) / points
    assert np.allclose(fourier_differentiation(points) @ np.sin(3 * T + 0.4), 3 * np.cos(3 * T + 0.4), atol=1e-12)


@pytest.mark.parametrize("name", ["paper", "piston", "plate:2"])
@pytest.mark.parametrize("sigma", [10.0, 96.0, 500.0])
@pytest.mark.parametrize("delta", [0.01, 0.1, 0.2])
def test_harmonic_balance_equals_time_marching_with_dT_to_zero(films, name, sigma, delta):
    """Same radial scheme; time marching's BDF2 error is O(dT^2), so its Richardson extrapolation from 128 and
    256 steps per period must meet the harmonic balance: within 3e-5 (observed <= 1.3e-5)."""
    marched = [periodic_film(SHAPES[name], sigma, delta, nodes=NODES, steps_per_period=steps, tolerance=1e-10).K
               for steps in (128, 256)]
    extrapolated = (4 * marched[1] - marched[0]) / 3
    K = films[name].K(sigma, delta)
    assert abs(K - extrapolated) <= 3e-5
    assert abs(K - marched[1]) <= 3e-4  # and the plain 256-step march is within its own time error


@pytest.mark.parametrize("name", ["paper", "piston"])
@pytest.mark.parametrize("sigma", [10.0, 96.0, 1000.0])
def test_harmonics_converge_spectrally(name, sigma):
    """At a gap swing delta max eps_hat = 0.7 the error against 16 harmonics falls from h = 3 to 6 to 8,
    and 6 harmonics (the default) are within 3e-6."""
    shape = SHAPES[name]
    films = {h: HarmonicBalanceFilm(shape, NODES, h) for h in (3, 6, 8, 16)}
    delta = 0.7 / films[16].largest_eps
    K = {h: film.K(sigma, delta) for h, film in films.items()}
    errors = [abs(K[h] - K[16]) for h in (3, 6, 8)]
    assert errors[0] > errors[1] > errors[2] and errors[1] <= 3e-6


@pytest.mark.parametrize("name", ["paper", "piston"])
def test_small_delta_is_the_perturbation_route(films, name):
    """delta -> 0: K(sigma, 1e-3) meets the same scheme's discrete delta -> 0 limit 2 sum V Pi_5 (eq. 11) within
    1e-5 (its O(delta^2) part), and perturbation_K within the O(dR^2) summation-by-parts term (docs/film_solvers.md)."""
    film, shape = films[name], SHAPES[name]
    R, faces, volumes = radial_grid(NODES)
    for sigma in (10.0, 96.0, 500.0):
        mean = discrete_mean_correction(shape, first_order_pressure(shape, sigma, NODES)[1], R, faces)
        K = film.K(sigma, 1e-3)
        assert K == pytest.approx(2 * np.sum(volumes * mean), abs=1e-5)
        assert K == pytest.approx(float(perturbation_K(shape, sigma, nodes=NODES)[0]), abs=3e-3)


def test_the_gap_limit_is_set_by_the_largest_excursion_of_either_sign():
    """A form whose trough is deeper than its peak closes the gap at the trough: delta is bounded by 1 / max |eps|."""
    radius = np.linspace(0.0, 1.0, 21)
    shape = TabulatedShape(radius, 0.5 - 2.5 * radius**2)  # +0.5 at the axis, -2.0 at the rim (before normalising)
    film = HarmonicBalanceFilm(shape, 11, 3)
    excursion = largest_excursion(shape(film.R))
    assert film.largest_eps == pytest.approx(excursion, rel=0.05) and excursion > 2 * np.max(shape(film.R))
    with pytest.raises(InvalidParameterError, match="delta"):
        film.solve(50.0, 1.05 / film.largest_eps)  # below 1 / max(eps_hat): it used to be accepted
    with pytest.raises(InvalidParameterError, match="delta"):
        periodic_film(shape, 50.0, 1.05 / film.largest_eps, nodes=11)


def test_bad_delta_is_an_error(films):
    with pytest.raises(InvalidParameterError, match="delta"):
        films["paper"].solve(96.0, 0.5)  # delta max eps_hat > 1: the gap closes
    with pytest.raises(InvalidParameterError, match="harmonics"):
        HarmonicBalanceFilm(SHAPES["paper"], NODES, 0)


@pytest.fixture(scope="module")
def tables():
    """The tables the plants use, from nfal's cache as they take them (4 s of solves when cold); that the cached
    table is the built one is tested below."""
    return {name: cached_table(SHAPES[name], nodes=NODES, harmonics=6, rig=RigParameters())
            for name in ("paper", "piston")}


@pytest.mark.parametrize("name", ["paper", "piston"])
def test_table_interpolates_the_direct_solution(tables, name):
    """Between its points the table is within 5e-5 of direct (Richardson-extrapolated) solves; the scalar
    fast path equals the array path."""
    table = tables[name]
    assert table.check() <= 5e-5
    for sigma, delta in ((1.0, 0.0), (33.0, 0.05), (250.0, 0.2), (1e6, 0.9)):
        assert table.scalar(sigma, delta) == pytest.approx(float(table(sigma, delta)), abs=1e-14)


@pytest.mark.slow  # the coupled model run
@pytest.mark.parametrize("name, amplitude, release, duration, transient, whole",
                         [("paper", 7e-6, 100e-6, 0.05, 0.0, 5e-4), ("piston", 3e-6, 70e-6, 0.15, 0.1, 5e-3)])
def test_averaged_plant_follows_the_coupled_model(tables, name, amplitude, release, duration, transient, whole):
    """Release from rest: the averaged plant (harmonic-balance K of the free object, eq. 6 damping) against
    the time-marched coupled model converged by Richardson extrapolation of 41 x 64 and 81 x 128. Heights
    within 5e-4 relative after ``transient`` s (observed: paper 1e-4 at release, 3e-7 settled; piston
    3e-5 at 0.15 s), and within ``whole`` throughout: the marched object's fast oscillation starts up at
    release and kicks its slow motion (piston: up to 4.1e-3 near 5 ms, decaying with the slow mode), which the
    averaged plant, released quasi-steady, has not. Fast oscillation chi within 2 %."""
    rig = RigParameters()
    runs = [CoupledModel(rig, SHAPES[name], nodes, steps, envelope=True).simulate(duration, amplitude, release)
            for nodes, steps in ((41, 64), (81, 128))]
    reference = runs[1].height + (runs[1].height - runs[0].height) / 3
    plant = AveragedFilmPlant(rig, tables[name])
    averaged = plant.simulate(duration, amplitude, release, samples=4001)
    error = np.abs(np.interp(runs[1].time, averaged.time, averaged.height) / reference - 1)
    assert np.max(error[runs[1].time >= transient]) <= 5e-4
    assert np.max(error) <= whole
    assert plant.oscillation(averaged.height[-1], amplitude) == pytest.approx(runs[1].oscillation[-1], rel=0.02)


def test_cached_table_is_the_built_one_and_keyed_by_its_settings(tmp_path, monkeypatch):
    settings = dict(nodes=11, harmonics=3, sigmas=6, richardson=False)
    built = cached_table(SHAPES["piston"], tmp_path, **settings)
    assert len(list((tmp_path / "film_tables").glob("*.npy"))) == 1
    with monkeypatch.context() as patch:  # a second build with the same settings must not solve again
        patch.setattr(FilmForceTable, "_solve_all", lambda self, film: pytest.fail("the cache was not read"))
        loaded = cached_table(SHAPES["piston"], tmp_path, **settings)
    assert np.array_equal(loaded.values, built.values) and loaded.scalar(50.0, 0.2) == built.scalar(50.0, 0.2)
    cached_table(SHAPES["paper"], tmp_path, **settings)  # another shape, another entry
    cached_table(SHAPES["piston"], tmp_path, **{**settings, "harmonics": 4})
    files = list((tmp_path / "film_tables").glob("*.npy"))
    assert len(files) == 3
    for file in files:
        file.write_bytes(b"not a table")
    assert np.array_equal(cached_table(SHAPES["piston"], tmp_path, **settings).values, built.values)  # rebuilt
