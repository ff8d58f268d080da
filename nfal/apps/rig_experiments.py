"""``nfal identify``'s experiments, run on a rig: equilibria and drive steps (Sec. 3.2.2, 3.3), with safety.

The experiments talk to the rig through a :class:`~nfal.apps.rig_io.RigIO`: :class:`~nfal.apps.rig_io.LinkRig`
over the rig protocol (:class:`~nfal.hil.link.RigLink`, any pyserial URL), or any object with the same ``exchange``
(a simulated rig in the tests). :class:`Experiments` sequences an
:class:`~nfal.models.identification.IdentificationPlan`:

* a **move** to a height closes the loop with the controller's own law (eqs. 21-22, the paper's design)
  from wherever the object is (at rest, the first move lifts it off), until the mean height over each half of
  the last 0.2 s is within the plan's tolerance and the mean drives of the halves agree within 1 %; the drive
  it needs there is the mean command of that time;
* a **hold** keeps a drive constant (open loop) until the height has settled (:func:`settled`, from the
  data) and records it; a move first, then a hold, is how an equilibrium is reached without waiting for
  the slow open-loop rise at large gaps (Sec. 3.3: about 9x slower near 190 um than eq. (6) predicts).

Safety: the drive is clamped to ``max_voltage`` (and the rig clamps to its own limit); DRIVE goes out with
every exchange, so the rig's watchdog trips only if the host or the link stalls; a **touchdown guard**
stops on a landing after lift-off; every fault raises :class:`ExperimentError` with its reason, and
:meth:`Experiments.ramp_down` lowers the drive (over ``RAMP_DOWN_S``, the object landing softly) before the
link says STOP. Every sample goes to the :class:`~nfal.apps.sample_recorder.SampleRecorder`'s CSV as it arrives.

Real time (docs/hil.md, "Real time that holds"): the experiments run inside a
:func:`~nfal.realtime.realtime_section` (the collector frozen after set-up and run only right after a DRIVE left);
the recorder keeps its samples in preallocated arrays, not as a Python object each, and the checks look at
fixed windows of them (searchsorted), so nothing inside the loop grows with the run. A stop signal
(:func:`~nfal.orchestration.interrupts.deferred_interrupts`) is honoured at the next exchange.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from nfal.apps.rig_io import RigIO, RigSample
from nfal.apps.sample_recorder import APPLIED, COMMANDED, HEIGHT, MAX_RECORDER_BYTES, SAMPLE_BYTES, TIME, SampleRecorder
from nfal.errors import ExperimentError, InvalidParameterError, PlanError
from nfal.models.calibration import paper_calibration
from nfal.models.control_law import DiscreteControlLaw
from nfal.models.identification import IdentificationPlan, settled
from nfal.models.pid_design import design_schedule
from nfal.models.plant import SimplifiedPlant
from nfal.models.rig import RigParameters
from nfal.models.stability import realizable_schedule
from nfal.models.table2 import SAMPLING_RATE_HZ

#: Below this clearance after lift-off the object is taken to have touched down [m].
TOUCHDOWN_M = 15e-6
#: The drive's ramp to 0 V after the experiments or a fault [s].
RAMP_DOWN_S = 0.3
#: A move has arrived when the mean height over this time is within tolerance [s]; its drive is the mean command
#: over it.
ARRIVAL_S = 0.2
#: The settling and arrival tests run this often [s] (not at every sample: the host must keep up with the rig).
CHECK_EVERY_S = 0.01
#: A move whose mean drive has been near the limit this long, the object still short of its height, cannot lift it [s].
LIMITED_S = 0.5
#: An equilibrium settled further than this from its height, relative, is held again at a corrected drive.
RETARGET = 0.03
#: Samples before a step kept with it (they pin its starting height) [s].
PRE_STEP_S = 0.05
#: Holds at one equilibrium at most: the first, and up to two at a corrected drive (:meth:`Experiments.equilibria`).
HOLD_ATTEMPTS = 3


def recorder_capacity(plan: IdentificationPlan, sample_period_s: float = 1 / SAMPLING_RATE_HZ) -> int:
    """Samples a run of ``plan`` can take at most (every move and hold to its limit, every equilibrium held
    HOLD_ATTEMPTS times), with 5 % to spare: the recorder never grows inside the loop. A plan whose columns would
    take more than :data:`MAX_RECORDER_BYTES` raises :class:`PlanError`."""
    _, longest = plan.duration_s()
    longest += (HOLD_ATTEMPTS - 1) * len(plan.equilibrium_heights_m) * plan.max_hold_s
    capacity = int(1.05 * longest / sample_period_s) + 4096
    if capacity * SAMPLE_BYTES > MAX_RECORDER_BYTES:
        raise PlanError(f"the plan's longest run (every move and hold to its limit) is {longest:,.0f} s of samples, "
                        f"{capacity * SAMPLE_BYTES / 2**30:,.1f} GiB held in memory; "
                        f"at most {MAX_RECORDER_BYTES >> 30} GiB: fewer heights or steps, or a shorter hold limit")
    return capacity


@dataclasses.dataclass(frozen=True)
class Equilibrium:
    """A held drive [V] and the settled height's mean and standard deviation [m] over the settling window."""

    voltage: float
    height: float
    spread: float


@dataclasses.dataclass(frozen=True)
class DriveStep:
    """A measured step of the drive: times [s] (0 at the step), heights [m], the voltages before and after [V]."""

    times: np.ndarray
    heights: np.ndarray
    voltage_before: float
    voltage_after: float


def move_law(plan: IdentificationPlan, *, metres_per_volt: float, max_voltage: float,
             schedule=None) -> DiscreteControlLaw:
    """The law of the moves: the Controller FMU's (the paper's gain schedule realisable at 2 kHz, ``schedule`` if
    given: design it before the port opens, it takes 0.3 s), its limit at ``max_voltage``."""
    heights = plan.equilibrium_heights_m + plan.damping_heights_m
    return DiscreteControlLaw(schedule or realizable_schedule(design_schedule()),
                              max_excitation_m=max_voltage * metres_per_volt,
                              reference_range_m=(min(heights), max(heights)))


class Experiments:
    """Runs a plan's experiments on ``rig`` (see the module docstring).

    Parameters
    ----------
    rig : RigIO
    plan : IdentificationPlan
    recorder : SampleRecorder
    metres_per_volt : float
        |a| per volt: turns the control law's excitation command into a drive voltage.
    max_voltage : float
        The drive never exceeds this [V].
    law : DiscreteControlLaw, optional
        The law of the moves (default :func:`move_law`).
    on_hold : callable, optional
        Called after each hold (for a progress bar).
    stop_request : StopRequest, optional
        Checked at each guarded exchange (:func:`~nfal.orchestration.interrupts.deferred_interrupts`): a stop signal
        raises there, between two exchanges, so the caller ramps the drive down from a consistent state.
    """

    def __init__(self, rig: RigIO, plan: IdentificationPlan, recorder: SampleRecorder, *, metres_per_volt: float,
                 max_voltage: float, law: DiscreteControlLaw | None = None, on_hold: Callable[[], None] | None = None,
                 stop_request=None) -> None:
        self.rig, self.plan, self.recorder = rig, plan, recorder
        self.metres_per_volt, self.max_voltage = metres_per_volt, max_voltage
        self.law = law or move_law(plan, metres_per_volt=metres_per_volt, max_voltage=max_voltage)
        self.on_hold = on_hold or (lambda: None)
        self.stop_request = stop_request
        # before the first DRIVE arms the rig's watchdog: the design model's excitations at the plan's heights (the
        # first root-finding call took 56 ms, 2.8 watchdog periods) and a first step of the law
        self._design = SimplifiedPlant(RigParameters(), paper_calibration())
        self._guesses = {h: self._guess(h) for h in plan.equilibrium_heights_m + plan.damping_heights_m}
        height = plan.equilibrium_heights_m[0]
        self.law.step(self.law.initial_state(height, self._guesses[height]), height, height)
        self.voltage = 0.0
        self.lifted = False

    # --- the experiments ---------------------------------------------------------------------------------
    def equilibria(self) -> list[Equilibrium]:
        """Each equilibrium height: move there, hold the drive found, record the settled window's statistics. A hold
        that settles more than RETARGET off its height (a move that arrived with its drive still on the way) is
        followed by up to two holds at the drive scaled by target / height (the height goes nearly as the drive):
        every hold is an equilibrium, and the work range stays covered."""
        points = []
        for i, target in enumerate(self.plan.equilibrium_heights_m):
            label = f"equilibrium {i + 1} ({target * 1e6:.0f} um)"
            voltage = self.move_to(target, label)
            for attempt in range(HOLD_ATTEMPTS):
                times, heights = self.hold(voltage, label if attempt == 0 else f"{label} again")
                window = heights[times >= times[-1] - self.plan.settle_window_s]
                points.append(Equilibrium(voltage, float(window.mean()), float(window.std())))
                if abs(points[-1].height / target - 1) <= RETARGET:
                    break
                voltage *= target / points[-1].height
        return points

    def damping_steps(self) -> list[list[DriveStep]]:
        """Each damping height: move there, step the drive down to -fraction (not fitted), then ``steps``
        times alternately up to +fraction and down; each step held until settled."""
        plan, result = self.plan, []
        for i, target in enumerate(plan.damping_heights_m):
            label = f"damping {i + 1} ({target * 1e6:.0f} um)"
            middle = self.move_to(target, label)
            low, high = middle * (1 - plan.step_fraction), middle * (1 + plan.step_fraction)
            self.hold(low, label + " start")
            steps = []
            for k in range(plan.steps):
                before, after = (low, high) if k % 2 == 0 else (high, low)
                times, _ = self.recorder.arrays()
                first = int(np.searchsorted(times, times[-1] - PRE_STEP_S))
                self.hold(after, f"{label} step {k + 1}")
                steps.append(self._step_since(first, before, after))
            result.append(steps)
        return result

    def _step_since(self, first: int, before: float, after: float) -> DriveStep:
        applied = self.recorder.column(APPLIED, first)
        at = int(np.argmax(np.abs(applied - after) < 1e-3 * max(after, 1.0)))
        times, heights = self.recorder.arrays(first)
        return DriveStep(times - times[at], heights.copy(), before, after)

    # --- moves and holds ---------------------------------------------------------------------------------
    def move_to(self, height: float, label: str) -> float:
        """Close the loop on ``height`` [m] until arrived; returns the mean drive over the arrival [V]."""
        law = self.law
        state = law.initial_state(self._last_height(), self.voltage * self.metres_per_volt
                                   or self._guesses.get(height) or self._guess(height))
        start, check_at = self._now(), -np.inf
        while True:
            samples = self._exchange(self.voltage, f"{label} move")
            for sample in samples:
                command, state = law.step(state, height, min(max(sample.height_m, 0.0), 1e-3))
            self.voltage = min(command / self.metres_per_volt, self.max_voltage)
            now, current = samples[-1].time_s, samples[-1].height_m
            if now >= check_at:
                check_at = now + CHECK_EVERY_S
                if now - start >= ARRIVAL_S and self._arrived(height):
                    return float(self._window(COMMANDED, now - ARRIVAL_S, now).mean())
                if now - start >= LIMITED_S and self._held_at_limit(height):
                    raise ExperimentError(f"{label}: the drive limit {self.max_voltage:g} V cannot lift the load to "
                                          f"{height * 1e6:.1f} um: at the limit for {LIMITED_S:g} s, the object is at "
                                          f"{current * 1e6:.1f} um (a load heavier than the rig can carry, or "
                                          "--max-voltage or --metres-per-volt too small?)")
            if now - start > self.plan.move_timeout_s:
                raise ExperimentError(f"{label}: the closed-loop move did not reach {height * 1e6:.1f} um within "
                                      f"{self.plan.move_timeout_s:g} s (at {current * 1e6:.1f} um, "
                                      f"drive {self.voltage:.3g} V)")

    def _window(self, column: int, low: float, high: float) -> np.ndarray:
        """A column's samples with rig time in [low, high) (a view; found by bisection: the cost does not grow
        with the run)."""
        times = self.recorder.column(TIME)
        first, last = np.searchsorted(times, (low, high))
        return self.recorder.column(column)[first:last]

    def _held_at_limit(self, height: float) -> bool:
        """Over the last LIMITED_S the drive is at the limit at least a fifth of the time (the rest is the law's
        answer to the sensor's noise) and the mean height is short of ``height`` by more than the tolerance."""
        now = self.recorder.last(TIME)
        window = (now - LIMITED_S, np.inf)
        short = self._window(HEIGHT, *window).mean() < height * (1 - self.plan.move_tolerance)
        return short and np.mean(self._window(COMMANDED, *window) >= 0.999 * self.max_voltage) >= 0.2

    def _arrived(self, height: float) -> bool:
        """Both halves of the last ARRIVAL_S: mean height within tolerance of ``height``, mean drives within 1 %."""
        now = self.recorder.last(TIME)
        halves = [(now - ARRIVAL_S, now - ARRIVAL_S / 2), (now - ARRIVAL_S / 2, np.inf)]
        for low, high in halves:
            if abs(self._window(HEIGHT, low, high).mean() - height) > self.plan.move_tolerance * height:
                return False
        drives = [self._window(COMMANDED, low, high).mean() for low, high in halves]
        return abs(drives[1] - drives[0]) <= 0.01 * drives[1]

    def hold(self, voltage: float, label: str) -> tuple[np.ndarray, np.ndarray]:
        """Hold ``voltage`` [V] open loop until the height has settled; returns the hold's (times, heights)."""
        self.voltage = min(float(voltage), self.max_voltage)
        first, start, check_at = self.recorder.count, self._now(), -np.inf
        while True:
            samples = self._exchange(self.voltage, label)
            if samples[-1].time_s < check_at:
                continue
            check_at = samples[-1].time_s + CHECK_EVERY_S
            times, heights = self.recorder.arrays(first)
            if settled(times, heights, self.plan.settle_window_s, self.plan.settle_drift):
                self.on_hold()
                return times, heights
            if samples[-1].time_s - start > self.plan.max_hold_s:
                window = heights[times >= times[-1] - self.plan.settle_window_s]
                raise ExperimentError(f"{label}: the height did not settle at {self.voltage:.4g} V within "
                                      f"{self.plan.max_hold_s:g} s: it moved {np.ptp(window) * 1e6:.2f} um over "
                                      f"the last {self.plan.settle_window_s:g} s (limit: halves' means within "
                                      f"{self.plan.settle_drift * 100:g} % of the height); a drifting or "
                                      "oscillating rig")

    def ramp_down(self) -> bool:
        """Lower the drive to 0 V over RAMP_DOWN_S (the object lands softly), and hold 0 V until the rig says it
        applies it (for up to RAMP_DOWN_S more): a caller's STOP then ends a session already at rest, and the rig's
        log shows the 0 V. False if the link failed meanwhile: then the rig's watchdog ramps the drive down."""
        start = self.recorder.last(TIME) if self.recorder.count else 0.0
        level = self.voltage
        try:
            while self.voltage > 0:
                samples = self._exchange(self.voltage, "ramp down", guard=False)
                self.voltage = max(0.0, level * (1 - (samples[-1].time_s - start) / RAMP_DOWN_S))
            # the samples that answer the first 0 V may have been measured before it arrived (a loaded host reads
            # them late): 2 of 6 runs of bench/realtime.py tests ended a session with the rig's last sample at
            # 0.16-1.24 V
            samples = self._exchange(0.0, "ramp down", guard=False)
            until = samples[-1].time_s + RAMP_DOWN_S
            while samples[-1].applied_voltage_v > 0 and samples[-1].time_s < until:
                samples = self._exchange(0.0, "ramp down", guard=False)
        except ExperimentError:
            return False
        return True

    # --- the exchange and its guards -----------------------------------------------------------------------
    def _exchange(self, voltage: float, label: str, guard: bool = True) -> list[RigSample]:
        samples = self.rig.exchange(voltage)
        self.recorder.add(samples, voltage, label)
        if not guard:
            return samples
        if self.stop_request is not None:
            self.stop_request.check()
        for sample in samples:
            if sample.watchdog_tripped:
                raise ExperimentError(f"{label}: the rig's watchdog tripped at rig time {sample.time_s:.3f} s "
                                      "(no DRIVE reached it in time: the host or the link stalled)")
            low = sample.resting or sample.height_m < TOUCHDOWN_M
            if self.lifted and low:
                raise ExperimentError(f"{label}: the object touched down (height {sample.height_m * 1e6:.1f} um, "
                                      f"drive {voltage:.3g} V) at rig time {sample.time_s:.3f} s")
            self.lifted = self.lifted or sample.height_m > 2 * TOUCHDOWN_M
        return samples

    def _now(self) -> float:
        return self.recorder.last(TIME) if self.recorder.count else self._exchange(self.voltage, "start")[-1].time_s

    def _last_height(self) -> float:
        self._now()
        return min(max(self.recorder.last(HEIGHT), 0.0), 1e-3)

    def _guess(self, height: float) -> float:
        """|a| [m] the design model needs at ``height`` (the integrator's start from rest)."""
        excitation = float(self._design.equilibrium_excitation(height))
        if not np.isfinite(excitation):
            raise InvalidParameterError("height", height, "one the design model can hold")
        return min(excitation, self.max_voltage * self.metres_per_volt)
