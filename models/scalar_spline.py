"""A scipy piecewise cubic evaluated at one point in plain Python floats.

scipy's spline call costs 5-8 us whatever the size of its argument; the plants' sub-steps and the 2 kHz control
law call their splines once per point, where this costs well under a microsecond. Outside its knots the value is
held at the end ones (the callers clamp; so does this).
"""

from __future__ import annotations

import bisect

import numpy as np


class ScalarSpline:
    """Scalar evaluation of a scipy ``PPoly`` (``CubicSpline``, ``PchipInterpolator``), 1-D or vector-valued."""

    def __init__(self, knots, coefficients) -> None:
        """``knots`` and ``coefficients`` as a ``PPoly``'s ``x`` and ``c`` (shape (order + 1, intervals, ...))."""
        self.knots = np.asarray(knots, dtype=float).tolist()
        # per interval, highest power first
        self._pieces = np.moveaxis(np.asarray(coefficients, dtype=float), 0, -1).tolist()

    @classmethod
    def of(cls, spline) -> "ScalarSpline":
        """The scalar view of a scipy ``PPoly`` (or a subclass)."""
        return cls(spline.x, spline.c)

    def piece(self, x: float) -> tuple[int, float]:
        """(interval, offset into it) of ``x``, clamped to the knots."""
        knots = self.knots
        x = min(max(x, knots[0]), knots[-1])
        i = min(bisect.bisect_right(knots, x) - 1, len(self._pieces) - 1)
        return i, x - knots[i]

    def __call__(self, x: float) -> float:
        """The (1-D) spline at ``x``."""
        i, dx = self.piece(x)
        c3, c2, c1, c0 = self._pieces[i]
        return ((c3 * dx + c2) * dx + c1) * dx + c0

    @property
    def pieces(self) -> list:
        """Per interval, per component, the cubic's coefficients, highest power first."""
        return self._pieces

    def values_in(self, i: int, dx: float) -> list[float]:
        """The vector-valued spline's components at offset ``dx`` into interval ``i`` (:meth:`piece`)."""
        return [((c3 * dx + c2) * dx + c1) * dx + c0 for c3, c2, c1, c0 in self._pieces[i]]
