"""Coloured measurement noise of Sec. 4.1 (Figs. 9-10): "maximal magnitude 2 um, cut-off 300 Hz".

White Gaussian samples at the loop's sampling rate pass through a second-order Butterworth low-pass
at the cut-off (zero initial state, after a burn-in of ``BURN_IN`` samples that is discarded), and the
record is scaled so that its largest magnitude is exactly ``peak_m``. The same seed gives the same record.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from .errors import InvalidParameterError, require_positive

#: Samples filtered and discarded before the record so it starts in the filter's steady state.
BURN_IN = 200


def coloured_noise(samples: int, *, sample_rate_hz: float = 2000.0, cutoff_hz: float = 300.0,
                   peak_m: float = 2e-6, seed: int | None = 0) -> np.ndarray:
    """``samples`` values [m] of low-pass filtered Gaussian noise whose peak magnitude is ``peak_m``.

    Parameters
    ----------
    samples : int
        Record length (one value per controller sample).
    sample_rate_hz : float
        Sampling rate [Hz].
    cutoff_hz : float
        -3 dB cut-off of the second-order Butterworth colouring filter [Hz]; below Nyquist.
    peak_m : float
        max |noise| [m] of the record; 0 gives zeros.
    seed : int or None
        Seed of the numpy Generator (PCG64).
    """
    if not isinstance(samples, (int, np.integer)) or samples < 1:
        raise InvalidParameterError("samples", samples, "a whole number >= 1")
    rate = require_positive("sample_rate_hz", sample_rate_hz)
    cutoff = require_positive("cutoff_hz", cutoff_hz)
    if cutoff >= rate / 2:
        raise InvalidParameterError("cutoff_hz", cutoff_hz, f"below the Nyquist frequency {rate / 2:g} Hz")
    if not (np.isfinite(peak_m) and peak_m >= 0):
        raise InvalidParameterError("peak_m", peak_m, "a finite amplitude >= 0 m")
    if peak_m == 0:
        return np.zeros(int(samples))
    white = np.random.default_rng(seed).standard_normal(int(samples) + BURN_IN)
    coloured = signal.sosfilt(signal.butter(2, cutoff, fs=rate, output="sos"), white)[BURN_IN:]
    return coloured * (peak_m / np.max(np.abs(coloured)))
