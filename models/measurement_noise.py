"""Coloured measurement noise of Sec. 4.1 (Figs. 9-10): "maximal magnitude 2 um, cut-off 300 Hz", streamed.

White Gaussian numbers from ``np.random.default_rng(seed)`` (PCG64) pass through the second-order
Butterworth low-pass at the cut-off, H(z) of ``scipy.signal.butter(2, cutoff, fs=rate)``. The paper's
"maximal magnitude" is read as a three-sigma bound:

    n_k = clip(s * (h * w)_k, -peak, +peak),     s = (peak / 3) / sqrt(sum_j h_j^2)

where h is the filter's impulse response, so sum_j h_j^2 is the exact variance of the filtered unit white
noise: the standard deviation is peak / 3 before clipping (0.997 peak / 3 after: 0.27 % of the samples
are clipped). Unlike a record normalised to its own maximum, this needs no look-ahead, so a streaming
source (the SensorChain FMU) and a whole record give the same numbers.

The generator works in fixed blocks of ``BLOCK`` white numbers, filtered as ``scipy.signal.sosfilt`` does with
the filter state carried from block to block, after a burn-in (filtered from zero state and discarded) long enough
for the start-up transient to decay below 1e-12 of the impulse response's peak (at least ``BURN_IN``
samples). Because the blocks do not depend on how the samples are consumed, ``next_sample()`` one at a
time, ``take(n)`` in any chunks, and :func:`coloured_noise` give bit-identical sequences for one seed.

The filter's design (:func:`butterworth_biquad`) and its recursion (:func:`biquad_filter`) are written here, not taken
from ``scipy.signal``: importing it takes 0.6-1 s (``python -X importtime -c "import scipy.signal"``), paid by
every process that sets up a SensorChain (each ``nfal run``, each rig emulator, each foreign host), for one
biquad. tests/test_closed_loop.py checks both against ``scipy.signal.butter`` and ``sosfilt``.
"""

from __future__ import annotations

import copy
import math

import numpy as np

from nfal.errors import InvalidParameterError, require_amplitude, require_positive

from .plausibility import MAX_CLEARANCE_M, require_plausible
from .table2 import NOISE_CUTOFF_HZ, NOISE_PEAK_M, SAMPLING_RATE_HZ

#: Least number of samples filtered and discarded so that the stream starts in the filter's steady state.
BURN_IN = 200
#: The lowest cut-off, as a fraction of the sample rate: the burn-in grows as 1 / cut-off (62 192 samples at this
#: bound; a 1e-6 Hz cut-off at 2 kHz would need 371 GiB for its impulse response).
MIN_CUTOFF_RATIO = 1e-4
#: White numbers drawn and filtered at a time (part of the definition of the sequence: do not change).
BLOCK = 256
#: The noise's peak is this many standard deviations (the clip level).
PEAK_SIGMAS = 3.0


def _check_settings(sample_rate_hz, cutoff_hz, peak_m) -> tuple[float, float, float]:
    rate = require_positive("sample_rate_hz", sample_rate_hz)
    cutoff = require_positive("cutoff_hz", cutoff_hz)
    if cutoff >= rate / 2:
        raise InvalidParameterError("cutoff_hz", cutoff_hz, f"below the Nyquist frequency {rate / 2:g} Hz")
    if cutoff < rate * MIN_CUTOFF_RATIO:
        raise InvalidParameterError("cutoff_hz", cutoff_hz, f"at least {rate * MIN_CUTOFF_RATIO:g} Hz (the sample rate "
                                    f"x {MIN_CUTOFF_RATIO:g}: a slower filter's start-up transient, filtered away at "
                                    f"set-up, grows as 1 / cut-off)")
    peak = require_amplitude("peak_m", peak_m)
    return rate, cutoff, require_plausible("peak_m", peak, MAX_CLEARANCE_M, "m")


def butterworth_biquad(cutoff_hz: float, sample_rate_hz: float) -> np.ndarray:
    """The second-order Butterworth low-pass at ``cutoff_hz`` as one second-order section ``[[b0, b1, b2, 1, a1,
    a2]]``: the bilinear transform with the cut-off prewarped, as ``scipy.signal.butter(2, cutoff_hz,
    fs=sample_rate_hz, output="sos")`` designs it."""
    k = math.tan(math.pi * cutoff_hz / sample_rate_hz)
    norm = 1.0 / (1.0 + math.sqrt(2.0) * k + k * k)
    b0 = k * k * norm
    return np.array([[b0, 2.0 * b0, b0, 1.0, 2.0 * (k * k - 1.0) * norm, (1.0 - math.sqrt(2.0) * k + k * k) * norm]])


def biquad_filter(sos: np.ndarray, x: np.ndarray, zi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``scipy.signal.sosfilt(sos, x, zi=zi)`` for one section: the transposed direct form II, operation for
    operation, so the same numbers to the bit."""
    b0, b1, b2, _, a1, a2 = sos[0].tolist()
    z0, z1 = zi[0].tolist()
    out = []
    for value in x.tolist():
        y = b0 * value + z0
        z0 = b1 * value - a1 * y + z1
        z1 = b2 * value - a2 * y
        out.append(y)
    return np.array(out), np.array([[z0, z1]])


class ColouredNoise:
    """A reproducible stream of low-pass filtered Gaussian noise [m] with standard deviation ``peak_m``/3, clipped.

    Parameters
    ----------
    sample_rate_hz : float
        Sampling rate [Hz] (one value per sample of the sensor or the loop; Table 2: 2000).
    cutoff_hz : float
        -3 dB cut-off of the second-order Butterworth colouring filter [Hz]; below Nyquist (Sec. 4.1: 300).
    peak_m : float
        Maximal magnitude [m] (Sec. 4.1: 2 um): three standard deviations and the clip level; 0 gives zeros.
    seed : int or None
        Seed of ``np.random.default_rng`` (PCG64). None draws fresh entropy (not reproducible).

    Examples
    --------
    >>> a = ColouredNoise(seed=3).take(5)
    >>> stream = ColouredNoise(seed=3)
    >>> bool(np.all(a == [stream.next_sample() for _ in range(5)]))
    True
    """

    def __init__(self, sample_rate_hz: float = SAMPLING_RATE_HZ, cutoff_hz: float = NOISE_CUTOFF_HZ,
                 peak_m: float = NOISE_PEAK_M, seed: int | None = 0) -> None:
        self.sample_rate_hz, self.cutoff_hz, self.peak_m = _check_settings(sample_rate_hz, cutoff_hz, peak_m)
        if seed is not None and not (isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and seed >= 0):
            raise InvalidParameterError("seed", seed, "a whole number >= 0 or None")
        self.seed = None if seed is None else int(seed)
        self._sos = butterworth_biquad(self.cutoff_hz, self.sample_rate_hz)
        pole_radius = float(np.max(np.abs(np.roots([1.0, *self._sos[0, 4:]]))))
        #: Samples discarded at the start: the transient (pole radius ** n) falls below 1e-12.
        self.burn_in = max(BURN_IN, int(math.ceil(math.log(1e-12) / math.log(pole_radius))))
        impulse = np.zeros(max(4 * self.burn_in, 1000))
        impulse[0] = 1.0
        #: Standard deviation of the filtered unit white noise: sqrt(sum h_j^2), the impulse response h.
        self.filter_gain = float(np.sqrt(np.sum(biquad_filter(self._sos, impulse, np.zeros((1, 2)))[0] ** 2)))
        self._scale = self.peak_m / PEAK_SIGMAS / self.filter_gain
        self._rng = np.random.default_rng(self.seed)
        self._zi = np.zeros((self._sos.shape[0], 2))
        self._buffer = np.empty(0)
        self._position = 0
        if self.peak_m > 0:
            _, self._zi = biquad_filter(self._sos, self._rng.standard_normal(self.burn_in), self._zi)

    @property
    def std_m(self) -> float:
        """The standard deviation [m] before clipping: ``peak_m`` / 3."""
        return self.peak_m / PEAK_SIGMAS

    def _refill(self) -> None:
        white = self._rng.standard_normal(BLOCK)
        filtered, self._zi = biquad_filter(self._sos, white, self._zi)
        self._buffer = np.clip(filtered * self._scale, -self.peak_m, self.peak_m)
        self._position = 0

    def peek(self) -> float:
        """The next value [m] without consuming it."""
        if self.peak_m == 0:
            return 0.0
        if self._position >= self._buffer.size:
            self._refill()
        return float(self._buffer[self._position])

    def next_sample(self) -> float:
        """The next value [m] of the stream."""
        if self.peak_m == 0:
            return 0.0  # no block, no position in it: a state taken now can be restored
        value = self.peek()
        self._position += 1
        return value

    @property
    def block(self) -> tuple[np.ndarray, int]:
        """The block of values being read and the position of the next in it (for a compiled reader:
        :mod:`~nfal.models.sensor_core`); an empty block before the first value."""
        return self._buffer, self._position

    def read_to(self, position: int) -> None:
        """A compiled reader took the block's values before ``position``."""
        self._position = int(position)

    def take(self, n: int) -> np.ndarray:
        """The next ``n`` values [m] of the stream (n >= 0), identical to ``n`` calls of :meth:`next_sample`."""
        if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < 0:
            raise InvalidParameterError("n", n, "a whole number >= 0")
        if self.peak_m == 0:
            return np.zeros(int(n))
        out = np.empty(int(n))
        filled = 0
        while filled < n:
            if self._position >= self._buffer.size:
                self._refill()
            chunk = min(int(n) - filled, self._buffer.size - self._position)
            out[filled:filled + chunk] = self._buffer[self._position:self._position + chunk]
            filled += chunk
            self._position += chunk
        return out

    def get_state(self) -> dict:
        """The generator's state (plain Python types, picklable and JSON-serialisable), for FMU state save."""
        return {"bit_generator": copy.deepcopy(self._rng.bit_generator.state), "zi": self._zi.tolist(),
                "buffer": self._buffer.tolist(), "position": int(self._position)}

    def set_state(self, state: dict) -> None:
        """Restore a state from :meth:`get_state` of a generator with the same settings."""
        try:
            zi = np.array(state["zi"], dtype=float).reshape(self._zi.shape)
            buffer = np.array(state["buffer"], dtype=float).ravel()
            position = int(state["position"])
            bit_generator = copy.deepcopy(state["bit_generator"])
            rng = np.random.default_rng()
            rng.bit_generator.state = bit_generator
        except (KeyError, TypeError, ValueError) as exc:
            raise InvalidParameterError("state", type(state).__name__,
                                        f"a state from ColouredNoise.get_state ({exc})") from None
        if not 0 <= position <= buffer.size:
            raise InvalidParameterError("state['position']", position, f"within [0, {buffer.size}]")
        self._rng, self._zi, self._buffer, self._position = rng, zi, buffer, position


def coloured_noise(samples: int, *, sample_rate_hz: float = SAMPLING_RATE_HZ, cutoff_hz: float = NOISE_CUTOFF_HZ,
                   peak_m: float = NOISE_PEAK_M, seed: int | None = 0) -> np.ndarray:
    """The first ``samples`` values [m] of :class:`ColouredNoise` (std ``peak_m``/3, clipped at ``peak_m``).

    Parameters
    ----------
    samples : int
        Record length (one value per controller sample), >= 1.
    sample_rate_hz, cutoff_hz, peak_m, seed
        As :class:`ColouredNoise`.
    """
    if not isinstance(samples, (int, np.integer)) or isinstance(samples, bool) or samples < 1:
        raise InvalidParameterError("samples", samples, "a whole number >= 1")
    return ColouredNoise(sample_rate_hz, cutoff_hz, peak_m, seed).take(int(samples))
