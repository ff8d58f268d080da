"""The Fig. 8 map: forward Euler (paper) and ZOH (digital loop) local stability."""

import numpy as np
import pytest

from nfal.errors import InvalidParameterError
from nfal.models.lpv import lpv_coefficients
from nfal.models.pid_design import design_pid, design_schedule
from nfal.models.rig import RigParameters
from nfal.models.stability import (continuous_loop_matrix, diagonal_moduli, max_pole_modulus, realizable_schedule,
                                   stability_map)

RIG = RigParameters()
GRID = np.linspace(50e-6, 200e-6, 16)
FE = stability_map(GRID, GRID)
ZOH = stability_map(GRID, GRID, discretisation="zoh")
STEP = RIG.omega / 2000.0


def test_forward_euler_moduli_are_one_plus_ts_times_the_designed_poles():
    d = design_pid(120e-6)
    poles = np.linalg.eigvals(continuous_loop_matrix(d.lpv, (d.kp, d.ki, d.kd), d.omega_lpf))
    np.testing.assert_allclose(np.sort_complex(poles), np.sort_complex(d.intended_poles("nondimensional")), rtol=1e-5)
    assert max_pole_modulus(d.lpv, (d.kp, d.ki, d.kd), d.omega_lpf, STEP) == \
        pytest.approx(np.max(np.abs(1 + STEP * poles)), rel=1e-7)


@pytest.mark.parametrize("grid", [FE, ZOH], ids=["forward_euler", "zoh"])
def test_margin_is_largest_on_the_diagonal(grid):
    """For every operating height whose own design is stable, that design has the smallest |z|
    (tolerance 1e-3: on the flat top of the ZOH map neighbours differ by less)."""
    for j in range(GRID.size):
        column = grid.max_pole_modulus[:, j]
        if column[j] < 1:
            assert column[j] <= column.min() + 1e-3, f"operating {GRID[j] * 1e6:.0f} um"


def test_forward_euler_map_is_below_one_where_the_fast_pair_fits_the_sampling():
    """Paper's claim holds on design and operating heights >= 100 um; below, see the trace bound."""
    upper = GRID >= 100e-6
    assert np.all(FE.max_pole_modulus[np.ix_(upper, upper)] < 1)
    assert FE.max_pole_modulus.min() == pytest.approx(0.9514, abs=1e-3)


def test_forward_euler_cannot_be_stable_below_65um_whatever_the_gains():
    """trace(A) = -(alpha1 + omega_L) needs > -8/T_s; every design is unstable at operating heights < 65 um."""
    low = GRID < 65e-6
    lpv = lpv_coefficients(GRID[low])
    wl = design_pid(100e-6).omega_lpf
    assert np.all(lpv.alpha1 + wl > 8 / STEP)
    assert np.all(FE.max_pole_modulus[:, low] > 1)


def test_zoh_loop_stable_on_the_diagonal_from_65um():
    diagonal = np.diag(ZOH.max_pole_modulus)
    assert np.all(diagonal[GRID >= 65e-6] < 1) and np.all(diagonal[GRID < 65e-6] > 1)


def test_realizable_schedule_starts_at_90um():
    schedule = design_schedule()
    trimmed = realizable_schedule(schedule)
    assert trimmed.height_range_m[0] == pytest.approx(90e-6)
    assert np.all(diagonal_moduli(trimmed) < 1)
    np.testing.assert_allclose(trimmed.gains_si(60e-6), schedule.gains_si(90e-6))


def test_map_dict_and_orientation():
    grid = stability_map([80e-6, 150e-6], [60e-6, 100e-6, 190e-6])
    data = grid.to_dict()
    assert np.shape(data["max_pole_modulus"]) == (2, 3)
    d = design_pid(150e-6)
    assert data["max_pole_modulus"][1][2] == pytest.approx(
        max_pole_modulus(lpv_coefficients(190e-6), (d.kp, d.ki, d.kd), d.omega_lpf, STEP), rel=1e-9)


@pytest.mark.parametrize("kwargs", [{"discretisation": "tustin"}, {"sample_rate_hz": -1}])
def test_bad_options_raise(kwargs):
    with pytest.raises(InvalidParameterError):
        stability_map([1e-4], [1e-4], **kwargs)
