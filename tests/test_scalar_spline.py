"""ScalarSpline: one point of a scipy piecewise cubic in plain floats, equal to scipy's own, held outside."""

import numpy as np
import pytest
from scipy import interpolate

from nfal.models.scalar_spline import ScalarSpline

X = np.array([0.0, 0.3, 1.1, 1.5, 2.7, 4.0])
RNG = np.random.default_rng(3)


@pytest.mark.parametrize("kind", [interpolate.CubicSpline, interpolate.PchipInterpolator])
def test_one_point_equals_scipy_and_is_held_outside(kind):
    spline = kind(X, RNG.normal(size=X.size))
    fast = ScalarSpline.of(spline)
    inside = np.concatenate([np.linspace(X[0], X[-1], 1001), X])
    np.testing.assert_allclose([fast(float(x)) for x in inside], spline(inside), rtol=1e-13, atol=1e-13)
    assert fast(-5.0) == pytest.approx(float(spline(X[0])), abs=1e-13)
    assert fast(9.0) == pytest.approx(float(spline(X[-1])), abs=1e-13)


def test_a_vector_valued_spline_gives_every_component():
    spline = interpolate.CubicSpline(X, RNG.normal(size=(X.size, 3)), axis=0)
    fast = ScalarSpline.of(spline)
    for x in np.linspace(X[0], X[-1], 97):
        np.testing.assert_allclose(fast.values_in(*fast.piece(float(x))), spline(x), rtol=1e-13, atol=1e-13)
