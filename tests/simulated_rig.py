"""A rig simulated in-process for the identification tests: a truth plant (eq. 13 with its own K, mass and excess
damping), the transducer's amplitude lag and the sensor's coloured noise, one 0.5 ms sample per exchange."""

from __future__ import annotations

import math
from collections.abc import Callable

from nfal.errors import ExperimentError
from nfal.apps.rig_io import RigSample
from nfal.models.fixed_step_plant import FixedStepPlant
from nfal.models.identification import AMPLITUDE_TIME_CONSTANT_S
from nfal.models.measurement_noise import ColouredNoise
from nfal.models.plant import PlantState, SimplifiedPlant
from nfal.realtime import LatencyStats

PERIOD_S = 5e-4


class SimulatedRig:
    """:class:`nfal.apps.rig_io.RigIO` played by ``truth`` (a SimplifiedPlant); the object starts at rest."""

    def __init__(self, truth: SimplifiedPlant, *, metres_per_volt: float = 1e-7, max_voltage: float = 150.0,
                 noise_peak_m: float = 2e-6, seed: int = 0, silent_after_s: float = math.inf,
                 gain: Callable[[float], float] = lambda t: 1.0, tripped_after_s: float = math.inf,
                 interrupt_at_s: float = math.inf) -> None:
        self.truth, self.plant = truth, FixedStepPlant(truth, near_surface="fast")
        self.metres_per_volt, self.max_voltage = metres_per_volt, max_voltage
        self.noise = ColouredNoise(1 / PERIOD_S, 300.0, noise_peak_m, seed) if noise_peak_m > 0 else None
        self.state = PlantState(truth.rest_gap, 0.0, True)
        self.excitation, self.time, self.silent_after_s, self.gain = 0.0, 0.0, silent_after_s, gain
        self.tripped_after_s, self.interrupt_at_s = tripped_after_s, interrupt_at_s
        self.decay = math.exp(-PERIOD_S / AMPLITUDE_TIME_CONSTANT_S)

    def exchange(self, voltage: float) -> list[RigSample]:
        if self.time > self.silent_after_s:
            raise ExperimentError("link lost: the simulated rig fell silent")
        if self.time > self.interrupt_at_s:
            self.interrupt_at_s = math.inf
            raise KeyboardInterrupt
        applied = min(max(voltage, 0.0), self.max_voltage)
        noise = self.noise.next_sample() if self.noise is not None else 0.0
        tripped = self.time > self.tripped_after_s
        applied = 0.0 if tripped else applied
        sample = RigSample(self.time, self.state.height + noise, 28500.0, applied, self.state.resting, tripped)
        self.state = self.plant.advance(self.state, self.excitation, PERIOD_S)
        target = self.metres_per_volt * self.gain(self.time) * applied
        self.excitation = target + (self.excitation - target) * self.decay
        self.time += PERIOD_S
        return [sample]

    def close(self) -> None:
        """Nothing to close (the link's counterpart)."""

    def safe_point(self) -> None:
        """Nothing runs in real time here."""

    def timing(self) -> dict:
        """No link: nothing was measured (the link's counterpart, LinkRig.timing)."""
        return {"drive_gaps": LatencyStats().report(), "sample_to_drive": LatencyStats().report()}
