"""A sampled block's clock as kernels on floats: which communication points are sample instants, and which step sizes
divide the sample period. :class:`~nfal.fmus.base.SampleClock` asks them, and so do the compiled cores
(``tracker_core.py``, ``sensor_core.py``), so that a core samples where the slave's Python does.
"""

from __future__ import annotations

import math

from . import jit


@jit.kernel
def sample_index(t, start, period, tolerance):
    """k if ``t`` is the sample instant start + k period (k >= 0) within ``tolerance`` relative to the larger of the
    period and t - start, else -1. (A tie rounds either way: it lies half a period from both instants.)"""
    elapsed = t - start
    k = math.floor(elapsed / period + 0.5)
    if k < 0 or abs(elapsed - k * period) > tolerance * max(period, abs(elapsed)):
        return -1
    return int(k)


@jit.kernel
def divides(period, step, tolerance):
    """Whether ``step`` goes a whole number of times (at least once) into ``period``, within ``tolerance`` relative."""
    ratio = period / step
    whole = math.floor(ratio + 0.5)
    return abs(ratio - whole) <= tolerance * ratio and whole >= 1
