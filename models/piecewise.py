"""The piecewise-polynomial form in which compiled code takes K(sigma, delta) or a damping factor (a *curve*).

``(log_axis, breaks, pieces, low, high, delta_max)``: the argument x is clamped to [low, high] (and taken as log x
when ``log_axis``); in the interval i of ``breaks`` that holds it the value is sum_p delta^(2p) poly(pieces[i, p],
x - breaks[i]), each poly's coefficients highest power first, |delta| held at delta_max. Evaluated by
:func:`nfal.models.slow_kernels.curve_value`. Made here, without numba, so that the calibrations that describe
themselves this way load no compiler.
"""

from __future__ import annotations

import numpy as np


def curve(log_axis: bool, breaks, pieces, low: float, high: float, delta_max: float) -> tuple:
    """A curve with the types every curve has (fresh float64 C arrays, floats): one compiled specialisation
    serves all."""
    pieces = np.array(pieces, dtype=float, order="C")
    return (bool(log_axis), np.array(breaks, dtype=float), pieces.reshape(pieces.shape[0], -1, pieces.shape[-1]),
            float(low), float(high), float(delta_max))


def spline_curve(spline, log_axis: bool, low: float, high: float) -> tuple:
    """A scipy piecewise cubic (``CubicSpline``, ``PchipInterpolator``) of x, or of log x when ``log_axis``, held at
    [low, high] of x, as a curve."""
    return curve(log_axis, spline.x, spline.c.T[:, np.newaxis, :], low, high, 0.0)


#: A curve of the right types for what does not use one (a damping correction without a table).
NO_CURVE = curve(False, [0.0, 1.0], np.zeros((1, 1, 1)), 0.0, 1.0, 0.0)
