"""SensorChain FMU: laser sensor, coloured noise, analog low-pass, sampling, quantisation (Fig. 7, Table 2).

A thin adapter over :class:`nfal.models.sensor_chain.SensorChain` (variables per docs/cosimulation.md):
it samples at ``sample_rate`` on the communication points a whole number of periods from the start, and
``measured_height`` is computed when read there (with the analog filter off it feeds through from
``true_height``; with it on it is the filter's state at that instant); ``doStep`` commits the sample, draws
the next noise value and integrates the filter exactly over the step with ``true_height`` held. The noise
is :class:`nfal.models.measurement_noise.ColouredNoise`: the same sequence as the pure-Python loop's
``coloured_noise`` for the same seed, sample rate, cut-off and peak. The filter starts in steady state at
the ``true_height`` set before initialisation ends.
"""

from __future__ import annotations

import sys

import numpy as np

from nfal.errors import InvalidParameterError
from nfal.fmus.base import CORE_TIME, SAMPLE_TOLERANCE, DefaultExperiment, NfalSlave, SampleClock
from nfal.models import sensor_chain as sensor_model
from nfal.models import sensor_core
from nfal.models.plausibility import MAX_CLEARANCE_M
from nfal.models.table2 import (ANALOG_FILTER_CUTOFF_HZ, NOISE_CUTOFF_HZ, NOISE_PEAK_M, SAMPLING_RATE_HZ,
                                STAIRCASE_LEVELS_M)


class SensorChain(NfalSlave):
    """True clearance in, sampled noisy filtered quantised measurement out."""

    description = ("Laser height sensor: true height + coloured noise -> analog 2nd-order Butterworth low-pass "
                   "-> sampling -> quantisation")
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=1.0, step_size=5e-4)

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.add_input("true_height", STAIRCASE_LEVELS_M[0], unit="m",
                       description="true clearance h of the levitated object")
        self.add_output("measured_height", unit="m", description="sampled, filtered, quantised measurement (held)",
                        depends_on=("true_height",), getter=self._measured)
        self.add_parameter("sample_rate", SAMPLING_RATE_HZ, unit="Hz", description="sampling rate")
        self.add_parameter("noise_peak", NOISE_PEAK_M, unit="m",
                           description="maximal noise magnitude (3 standard deviations, clip level); 0: none")
        self.add_parameter("noise_cutoff", NOISE_CUTOFF_HZ, unit="Hz",
                           description="cut-off of the noise's colouring filter")
        self.add_parameter("seed", 0, description="seed of the noise (>= 0)")
        self.add_parameter("analog_cutoff", ANALOG_FILTER_CUTOFF_HZ, unit="Hz",
                           description="cut-off of the analog 2nd-order Butterworth low-pass; 0: no filter")
        self.add_parameter("resolution", 0.0, unit="m", description="quantisation step; 0: none")
        self._chain: sensor_model.SensorChain | None = None
        self._clock: SampleClock | None = None
        self._state: sensor_model.SensorState | None = None

    def _build(self) -> None:
        if self.seed < 0:
            raise InvalidParameterError("seed", self.seed, "a whole number >= 0")
        chain = sensor_model.SensorChain(sample_rate_hz=self.sample_rate, noise_peak_m=self.noise_peak,
                                         noise_cutoff_hz=self.noise_cutoff, seed=int(self.seed),
                                         analog_cutoff_hz=self.analog_cutoff, resolution_m=self.resolution)
        self._chain, self._clock = chain, SampleClock(chain.period_s, self.start_time)

    def setup(self) -> None:
        self._chain = self._clock = self._state = None
        self._build()
        self._state = self._chain.initial_state(self.true_height)

    def _outputs_of_the_state(self) -> frozenset[str]:
        """Behind the analog filter the measurement is the filter's sampled state, whatever true_height is now."""
        return frozenset({"measured_height"}) if self._chain is not None and self._chain.filtered else frozenset()

    def _measured(self) -> float:
        if self._state is None:  # before initialisation ends
            return float(self.true_height)
        at_sample = self._clock.is_sample(self.time)
        if self._chain.filtered:  # an output of the state: the height is checked where it is read, by the step
            return self._chain.filtered_output(self._state, at_sample=at_sample)
        return self._chain.output(self._state, self.true_height, at_sample=at_sample)

    def step(self, current_time: float, step_size: float) -> None:
        self._clock.check_step(step_size)
        self._state = self._chain.advance(self._state, self.true_height, step_size,
                                          at_sample=self._clock.is_sample(current_time))

    # --- the compiled core: the runtime steps the chain without Python (models/sensor_core.py) ---------------
    def _core_address(self) -> int | None:
        if not self._outputs_of_the_state() or self._chain.resolution_m != 0 or "numba" not in sys.modules:
            return None  # a measurement fed through or quantised is the slave's; numba's start would cost more
        return sensor_core.step_address()  # compiled, or loaded from numba's cache, on first use

    def _packed_core(self) -> np.ndarray:
        """Its clock, its state, its noise block (packed again where the slave's Python stepped: every 256 samples,
        where the block is used up) and the filter's discretisation."""
        slots = (self._cache_slot("true_height"), self._cache_slot("measured_height"), CORE_TIME)
        block, position = self._chain.noise.block
        return sensor_core.pack(slots, MAX_CLEARANCE_M, SAMPLE_TOLERANCE, self._clock.start_time_s,
                                self._clock.period_s, sensor_model.STEP_TOLERANCE, self._chain.discretisation,
                                self._chain.noise.peak_m > 0, self._state, position, block)

    def _take_core_state(self) -> None:
        y, rate, noise, measured, position, _ = self._core_data[sensor_core.STATE:sensor_core.BLOCK_START].tolist()
        self._state = sensor_model.SensorState((y, rate), noise, measured)
        self._chain.noise.read_to(int(position))

    def get_internal_state(self) -> dict:
        return {} if self._state is None else self._chain.get_state(self._state)

    def set_internal_state(self, state: dict) -> None:
        if not state:
            self._state = None
            return
        if self._chain is None:
            self._build()
        self._state = self._chain.set_state(state)
