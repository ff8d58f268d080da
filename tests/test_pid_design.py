"""Double-pair pole placement of eqs. (23)-(24), checked with python-control, and the gain schedule."""

import math
import os
import subprocess
import sys

import control
import numpy as np
import pytest
import scipy.interpolate

from nfal.errors import InvalidParameterError
from nfal.models.rig import RigParameters
from nfal.models.pid_design import DesignSpec, FixedGains, GainSchedule, design_pid, design_schedule, fixed_design

SCHEDULE = design_schedule()  # 50-200 um every 5 um
HALF_POWER_DB = 20 * math.log10(1 / math.sqrt(2))


@pytest.mark.parametrize("design", SCHEDULE.designs, ids=lambda d: f"{d.height_m * 1e6:.0f}um")
def test_loop_poles_are_the_intended_double_pairs(design):
    """Block-diagram loop (python-control) poles equal -p1, -p1, -p2, -p2 within 1e-5 relative."""
    intended = np.sort_complex(design.intended_poles())
    got = design.loop_poles()
    assert np.max(np.abs(got - intended) / np.abs(intended)) < 1e-5
    assert np.all(np.abs(got.imag) < 1e-5 * np.abs(got.real))
    np.testing.assert_allclose(np.sort_complex(control.poles(design.closed_loop())), intended, rtol=1e-5)


@pytest.mark.parametrize("design", SCHEDULE.designs[::3], ids=lambda d: f"{d.height_m * 1e6:.0f}um")
def test_closed_loop_bandwidth_is_the_cutoff_and_dc_gain_one(design):
    tf = design.closed_loop()
    assert control.bandwidth(tf, dbdrop=HALF_POWER_DB) / (2 * math.pi) == pytest.approx(10.0, abs=1e-3)
    assert control.dcgain(tf) == pytest.approx(1.0, abs=1e-9)
    assert design.slow_pole + design.fast_pole == pytest.approx((float(design.lpv.alpha1) + design.omega_lpf) / 2,
                                                                rel=1e-12)


def test_gains_are_positive_over_the_work_range():
    kp, ki, kd = (np.array([getattr(d, k) for d in SCHEDULE.designs]) for k in ("kp_si", "ki_si", "kd_si"))
    assert np.all(kp > 0) and np.all(ki > 0) and np.all(kd >= 0)


def test_schedule_interpolates_direct_designs_between_knots():
    """Midpoints of the 5 um table: spline gains within 1 % (kp, ki) of a direct design; kd within 1 % of its range."""
    for h in np.linspace(52.5e-6, 197.5e-6, 30):
        direct = design_pid(h)
        kp, ki, kd = SCHEDULE.gains_si(h)
        assert kp == pytest.approx(direct.kp_si, rel=1e-2)
        assert ki == pytest.approx(direct.ki_si, rel=1e-2)
        assert abs(kd - direct.kd_si) < 1e-2 * abs(direct.kd_si) + 1e-7


def test_schedule_is_continuously_differentiable():
    """The spline's slope matches a finite difference of the spline and is continuous across every knot."""
    H = SCHEDULE.heights_m / SCHEDULE.reference_clearance
    step = 1e-7
    for knot in SCHEDULE.heights_m[1:-1]:
        below = SCHEDULE.slope_nondimensional(knot - step * 1e-4)
        above = SCHEDULE.slope_nondimensional(knot + step * 1e-4)
        np.testing.assert_allclose(below, above, rtol=1e-4, atol=1e-12)
    h = 123.4e-6
    numeric = (SCHEDULE.gains_nondimensional(h + 1e-10) - SCHEDULE.gains_nondimensional(h - 1e-10)) / (2e-10 / 1e-4)
    np.testing.assert_allclose(SCHEDULE.slope_nondimensional(h), numeric, rtol=1e-5)
    assert H[0] == pytest.approx(0.5)


def test_gains_held_outside_the_table():
    np.testing.assert_allclose(SCHEDULE.gains_si(30e-6), SCHEDULE.gains_si(50e-6))
    np.testing.assert_allclose(SCHEDULE.gains_si(300e-6), SCHEDULE.gains_si(200e-6))


def test_fixed_design_is_constant_and_equals_its_design():
    fixed = fixed_design(120e-6)
    assert isinstance(fixed, FixedGains)
    for h in (60e-6, 120e-6, 180e-6):
        np.testing.assert_allclose(fixed.gains_si(h), SCHEDULE.gains_si(120e-6), rtol=1e-9)


def test_si_gain_units():
    d = design_pid(100e-6)
    assert d.ki_si == pytest.approx(d.ki * d.lpv.omega) and d.kd_si == pytest.approx(d.kd / d.lpv.omega)


@pytest.mark.parametrize("kwargs", [{"closed_loop_cutoff_hz": 0}, {"filter_cutoff_hz": -300},
                                    {"closed_loop_cutoff_hz": math.nan}])
def test_bad_spec_raises(kwargs):
    with pytest.raises(InvalidParameterError):
        DesignSpec(**kwargs)


def test_unreachable_cutoff_raises():
    with pytest.raises(InvalidParameterError, match="closed_loop_cutoff_hz"):
        design_pid(200e-6, spec=DesignSpec(closed_loop_cutoff_hz=1.0))


def test_unknown_keyword_raises():
    with pytest.raises(TypeError):
        design_pid(100e-6, cutoff=10)


def test_the_cached_gain_spline_is_scipys_not_a_knot_spline(tmp_path, monkeypatch):
    """The schedule's spline, read back from the cache, is scipy's CubicSpline of the designs, value and slope; a
    corrupt entry is fitted again."""
    monkeypatch.setenv("NFAL_CACHE_DIR", str(tmp_path))
    designs = design_schedule(np.linspace(60e-6, 180e-6, 7)).designs
    expected = scipy.interpolate.CubicSpline([d.height_m / designs[0].lpv.reference_clearance for d in designs],
                                             [[d.kp, d.ki, d.kd] for d in designs], axis=0)
    heights = np.linspace(55e-6, 185e-6, 53)
    for attempt in range(3):
        schedule = GainSchedule(designs)
        H = np.clip(heights, *schedule.height_range_m) / schedule.reference_clearance
        np.testing.assert_allclose(schedule.gains_nondimensional(heights), expected(H), rtol=1e-14, atol=0)
        inside = (heights >= 60e-6) & (heights <= 180e-6)
        np.testing.assert_allclose(schedule.slope_nondimensional(heights)[inside], expected(H[inside], 1), rtol=1e-12)
        assert schedule.law_terms(100e-6)[0] == pytest.approx(float(expected(100e-6 / schedule.reference_clearance)[0]),
                                                              rel=1e-13)
        [entry] = (tmp_path / "gain_splines").glob("*.npy")
        if attempt == 1:
            np.save(entry, np.zeros((4, 2, 3)))  # the wrong shape: fitted again


@pytest.mark.slow
def test_a_controller_whose_design_is_cached_imports_no_scipy_interpolate(tmp_path):
    """The Controller FMU's set-up in a host's process: with its design and gain spline in the cache, it needs no
    scipy.interpolate (and none of the scipy.optimize, .special and .sparse that it brings: 0.6-0.7 s)."""
    code = ("import sys\n"
            "from nfal.fmus.controller import Controller\n"
            "slave = Controller(instance_name='c')\n"
            "slave.setup_experiment(0.0); slave.enter_initialization_mode(); slave.exit_initialization_mode()\n"
            "slave.do_step(0.0, 5e-4)\n"
            "print(sorted(m for m in ('scipy.interpolate', 'scipy.optimize', 'scipy.special') if m in sys.modules))\n")
    env = {**os.environ, "NFAL_CACHE_DIR": str(tmp_path)}
    outputs = [subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
               for _ in range(2)]
    assert outputs[0].strip() != "[]"  # the first designs and fits (the test would pass for nothing otherwise)
    assert outputs[1].strip() == "[]"


def test_a_schedule_is_kept_across_processes_and_keyed_by_what_it_depends_on(tmp_path, monkeypatch):
    """The cached schedule equals the designed one field for field; another spec or rig is another entry; an entry
    that does not fit (a corrupt or foreign file) is designed again."""
    import nfal.models.pid_design as pid_design

    monkeypatch.setenv("NFAL_CACHE_DIR", str(tmp_path))
    spec, heights = DesignSpec(sample_rate_hz=2000.0, reference_zero=1.0), np.linspace(60e-6, 180e-6, 4)
    designed = design_schedule(heights, spec=spec)
    with monkeypatch.context() as patch:  # the same inputs must not design again
        patch.setattr(pid_design, "design_at", lambda *args: pytest.fail("the cache was not read"))
        assert design_schedule(heights, spec=spec).designs == designed.designs
    design_schedule(heights, spec=DesignSpec(sample_rate_hz=2000.0))
    design_schedule(heights, rig=RigParameters(mass=0.15), spec=spec)
    files = list((tmp_path / "pid_designs").glob("*.npy"))
    assert len(files) == 3
    for file in files:
        np.save(file, np.zeros((2, 2)))
    assert design_schedule(heights, spec=spec).designs == designed.designs
