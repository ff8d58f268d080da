import math

import numpy as np
import pytest

from nfal.errors import InvalidParameterError
from nfal.models.rig import RigParameters


@pytest.mark.parametrize("field", ["mass", "radius", "frequency", "viscosity", "ambient_pressure", "gravity",
                                   "reference_clearance"])
@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf"), "x"])
def test_invalid_values_name_the_field(field, bad):
    with pytest.raises(InvalidParameterError, match=field):
        RigParameters(**{field: bad})


@pytest.mark.parametrize("field, slip, hint", [
    ("frequency", 28.5, "kHz as Hz"), ("frequency", 28.5e6, "kHz as Hz"),
    ("ambient_pressure", 101.325, "kPa, hPa or bar"), ("ambient_pressure", 1013.25, "kPa, hPa or bar"),
    ("ambient_pressure", 1.01325, "kPa, hPa or bar"),
    ("viscosity", 18.1, "µPa s or mPa s"), ("gravity", 981.0, "check the unit"), ("mass", 134.7, "grams as kg"),
])
def test_unit_slips_are_refused_with_a_hint(field, slip, hint):
    with pytest.raises(InvalidParameterError, match=f"^{field} = .* for a levitation rig \\(.*{hint}"):
        RigParameters(**{field: slip})


@pytest.mark.parametrize("field, value", [("frequency", 2e3), ("frequency", 100e3), ("ambient_pressure", 5e4),
                                          ("viscosity", 1.2e-5), ("gravity", 1.62)])
def test_plausible_rigs_are_accepted(field, value):
    """Table 1's 2 kHz rig, an ultrasonic one, half an atmosphere, helium-like gas, the Moon."""
    assert getattr(RigParameters(**{field: value}), field) == value


def test_unknown_field_is_an_error():
    with pytest.raises(TypeError):
        RigParameters(weight=1.0)


def test_groups_of_eq14_are_consistent_with_dimensional_forces():
    rig = RigParameters()
    h0 = rig.reference_clearance
    # C_s* u^2 K / H^2 [non-dim accel] * m omega^2 h0 = pi r0^2 p_a delta^2 K [N]
    u, H, K = 0.03, 1.2, 0.7
    force = rig.stiffness_coefficient * u**2 * K / H**2 * rig.mass * rig.omega**2 * h0
    assert force == pytest.approx(rig.film_force_scale * (u / H) ** 2 * K, rel=1e-12)
    # C_d / H^3 dH/dT equals the dimensional damping c(h) hdot / (m omega^2 h0)
    hdot = 1e-3
    lhs = rig.damping_coefficient / H**3 * (hdot / (h0 * rig.omega))
    assert lhs == pytest.approx(rig.squeeze_film_damping(H * h0) * hdot / (rig.mass * rig.omega**2 * h0), rel=1e-12)
    assert rig.gravity_term == pytest.approx(rig.gravity / (rig.omega**2 * h0))


def test_squeeze_number_and_its_inverse():
    rig = RigParameters()
    h = np.array([25e-6, 100e-6, 200e-6])
    sigma = rig.squeeze_number(h)
    assert sigma[1] == pytest.approx(12 * 1.81e-5 * 2 * math.pi * 28.5e3 * 0.05**2 / (101325 * 1e-8))
    np.testing.assert_allclose(rig.clearance_at(sigma), h, rtol=1e-12)
