"""``nfal identify``'s experiments, run on a rig: equilibria and drive steps (Sec. 3.2.2, 3.3), with safety.

The experiments talk to the rig through a :class:`RigIO`: :class:`LinkRig` over the rig protocol
(:class:`~nfal.hil.link.RigLink`, any pyserial URL), or any object with the same ``exchange`` (a simulated
rig in the tests). :class:`Experiments` sequences an :class:`~nfal.models.identification.IdentificationPlan`:

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
link says STOP. Every sample goes to the :class:`SampleRecorder`'s CSV as it arrives.

Real time (docs/hil.md, "Real time that holds"): the experiments run inside a
:func:`~nfal.realtime.realtime_section` (the collector frozen after set-up and run only right after a DRIVE left);
the recorder keeps its samples in preallocated arrays, not as a Python object each, and the checks look at
fixed windows of them (searchsorted), so nothing inside the loop grows with the run. A stop signal
(:func:`~nfal.orchestration.interrupts.deferred_interrupts`) is honoured at the next exchange.
"""

from __future__ import annotations

import csv
import dataclasses
from typing import Callable, Protocol, TextIO

import numpy as np

from nfal.errors import ExperimentError, InvalidParameterError, PlanError
from nfal.hil.link import RigLink, Sample
from nfal.hil.protocol import StatusFlags
from nfal.realtime import LatencyStats
from nfal.models.calibration import RigCalibration, paper_calibration, rig_record
from nfal.models.control_law import DiscreteControlLaw
from nfal.models.damping import DampingCorrection
from nfal.models.measured_calibration import FIT_DEGREE, EquilibriumData, ExperimentalCalibration, fit_calibration
from nfal.models.identification import (AMPLITUDE_TIME_CONSTANT_S, IdentificationPlan, StepFit, damping_table, fit_step,
                                        settled)
from nfal.models.pid_design import design_schedule
from nfal.models.plant import SimplifiedPlant
from nfal.models.rig import RigParameters
from nfal.models.stability import realizable_schedule
from nfal.models.table2 import SAMPLING_RATE_HZ

#: Below this clearance after lift-off the object is taken to have touched down [m].
TOUCHDOWN_M = 15e-6
#: Longest silence of the rig before the link counts as lost [s] (a loaded host can pause the emulator ~0.1 s).
MAX_SILENCE_S = 0.5
#: Longest wait for the port between two checks of the link [s].
SILENCE_CHECK_S = 0.01
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
#: Memory of one sample in the recorder's columns [bytes], and the most the columns may take: they are preallocated
#: for the plan's longest run, and 8 GiB hold about 30 h of samples at 2 kHz.
SAMPLE_BYTES = 5 * 8
MAX_RECORDER_BYTES = 8 << 30
#: The CSV's columns.
CSV_HEADER = ("rig_time_s", "height_m", "drive_frequency_hz", "applied_voltage_v", "commanded_voltage_v", "resting",
              "experiment")


@dataclasses.dataclass(frozen=True)
class RigSample:
    """One measurement: rig time [s], height [m], drive frequency [Hz], applied voltage [V], resting, watchdog."""

    time_s: float
    height_m: float
    drive_frequency_hz: float
    applied_voltage_v: float
    resting: bool
    watchdog_tripped: bool = False


class RigIO(Protocol):
    """Send the drive for the next period, get the samples measured since the last call (at least one); call
    ``safe_point`` right after the drive left; ``timing`` reports the loop's margin (:meth:`LinkRig.timing`)."""

    safe_point: Callable[[], None]

    def exchange(self, voltage: float) -> list[RigSample]: ...

    def timing(self) -> dict: ...

    def close(self) -> None: ...


class LinkRig:
    """:class:`RigIO` over a :class:`RigLink` (opened here; closed with STOP by :meth:`close`).

    ``safe_point`` (default: nothing) is called right after each DRIVE left, where the loop has the most slack before
    the next sample (a real-time section's collector); :attr:`lateness` holds the age of the newest sample when the
    DRIVE answering it left, and the link's ``drive_gaps`` the gaps between DRIVE commands."""

    def __init__(self, url: str, *, connect_timeout_s: float = 2.0, max_silence_s: float = MAX_SILENCE_S) -> None:
        self._new: list[RigSample] = []
        self._newest_arrival: float | None = None
        self.lateness = LatencyStats()
        self.safe_point: Callable[[], None] = lambda: None
        self.link = RigLink(url, connect_timeout_s=connect_timeout_s, reconnect=False, reader_thread=False,
                            on_sample=self._take)
        self.hello = self.link.open()
        self.max_silence_s = max_silence_s

    def _take(self, sample: Sample) -> None:
        m = sample.measurement
        self._newest_arrival = sample.arrival_s
        self._new.append(RigSample(m.timestamp_us * 1e-6, m.height, m.drive_frequency, m.drive_voltage,
                                   bool(m.status & StatusFlags.RESTING), bool(m.status & StatusFlags.WATCHDOG_TRIPPED)))

    def exchange(self, voltage: float) -> list[RigSample]:
        link = self.link
        if self._newest_arrival is not None:
            self.lateness.add(link.clock() - self._newest_arrival)
        link.send_drive(voltage)
        self.safe_point()
        deadline = link.clock() + self.max_silence_s
        while True:
            link.poll()
            if self._new:
                new, self._new = self._new, []
                return new
            now = link.clock()
            if now > deadline or not link.connected:
                reason = link.last_error or "the rig fell silent"
                raise ExperimentError(f"link lost: no measurement from {link.url} for "
                                      f"{self.max_silence_s * 1e3:.0f} ms ({reason})")
            link.wait_readable(min(deadline - now, SILENCE_CHECK_S))

    def timing(self) -> dict:
        """The margin to the rig's watchdog: gaps between DRIVE commands leaving the host, and the age of the newest
        sample when the DRIVE answering it left [s] (count, mean, p50, p99, max)."""
        return {"drive_gaps": self.link.drive_gaps.report(), "sample_to_drive": self.lateness.report()}

    def close(self) -> None:
        self.link.close()


#: The recorder's columns, in :attr:`SampleRecorder.columns`' rows.
TIME, HEIGHT, FREQUENCY, APPLIED, COMMANDED = range(5)


class SampleRecorder:
    """Every sample in preallocated columns (rig time, height, drive frequency, applied and commanded voltage: no
    Python object per sample, so the collector has nothing to walk) and streamed to ``stream`` as CSV (flushed
    every 0.1 s of rig time). ``capacity``: samples held before the columns grow (a copy: give the run's bound,
    :func:`recorder_capacity`). Make it before the first DRIVE: its pages are touched here (numpy asks the kernel for
    huge pages for large arrays, and the first write to each cost 8 ms: 39 ms for the first samples, measured)."""

    def __init__(self, stream: TextIO | None = None, capacity: int = 1 << 14) -> None:
        self.count = 0
        self.columns = _touched((5, max(int(capacity), 16)))
        self._writer = None if stream is None else csv.writer(stream)
        self._stream, self._flushed_at = stream, -np.inf
        if self._writer is not None:
            self._writer.writerow(CSV_HEADER)

    def add(self, samples: list[RigSample], commanded: float, label: str) -> None:
        n, count = self.count, len(samples)
        if n + count > self.columns.shape[1]:
            grown = _touched((5, 2 * (n + count)))
            grown[:, :n] = self.columns[:, :n]
            self.columns = grown
        rows = self.columns[:, n:n + count]
        rows[TIME] = [s.time_s for s in samples]
        rows[HEIGHT] = [s.height_m for s in samples]
        rows[FREQUENCY] = [s.drive_frequency_hz for s in samples]
        rows[APPLIED] = [s.applied_voltage_v for s in samples]
        rows[COMMANDED] = commanded
        self.count = n + count
        if self._writer is None:
            return
        self._writer.writerows((repr(s.time_s), repr(s.height_m), repr(s.drive_frequency_hz), repr(s.applied_voltage_v),
                                repr(commanded), int(s.resting), label) for s in samples)
        if samples and samples[-1].time_s - self._flushed_at > 0.1:
            self._stream.flush()
            self._flushed_at = samples[-1].time_s

    def column(self, index: int, start: int = 0) -> np.ndarray:
        """One column (TIME, HEIGHT, FREQUENCY, APPLIED or COMMANDED) from sample ``start`` on (a view: do not keep it
        across :meth:`add`)."""
        return self.columns[index, start:self.count]

    def arrays(self, start: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """(times [s], heights [m]) of the samples from ``start`` on (views: do not keep them across ``add``)."""
        return self.column(TIME, start), self.column(HEIGHT, start)

    def last(self, index: int) -> float:
        """The newest sample's value in a column."""
        return float(self.columns[index, self.count - 1])

    @property
    def duration_s(self) -> float:
        return self.last(TIME) - float(self.columns[TIME, 0]) if self.count else 0.0


def _touched(shape: tuple[int, int]) -> np.ndarray:
    """An array of NaN whose every page has been written (no page fault left for the loop)."""
    return np.full(shape, np.nan)


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
        """Lower the drive to 0 V over RAMP_DOWN_S (the object lands softly). False if the link failed meanwhile:
        then the rig's watchdog ramps the drive down."""
        start = self.recorder.last(TIME) if self.recorder.count else 0.0
        level = self.voltage
        try:
            while self.voltage > 0:
                samples = self._exchange(self.voltage, "ramp down", guard=False)
                self.voltage = max(0.0, level * (1 - (samples[-1].time_s - start) / RAMP_DOWN_S))
            self._exchange(0.0, "ramp down", guard=False)
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


@dataclasses.dataclass(frozen=True)
class Identification:
    """What the experiments identified: K(sigma) (eqs. 16-17), the damping table, and the data behind them."""

    calibration: ExperimentalCalibration
    equilibria: list[Equilibrium]
    damping: DampingCorrection
    rig: RigParameters
    step_fits: list[list[StepFit]]
    steps: list[list[DriveStep]]
    metres_per_volt: float

    def document(self, provenance: dict) -> dict:
        """The calibration file (:class:`RigCalibration`: K, ``damping``, the ``rig`` it was identified on and
        ``provenance``), plus the ``equilibria`` behind K."""
        calibration = RigCalibration(self.calibration.fit, self.damping, rig_record(self.rig), provenance)
        return {**calibration.to_dict(),
                "equilibria": {"voltage_v": [p.voltage for p in self.equilibria],
                               "height_m": [p.height for p in self.equilibria],
                               "height_spread_m": [p.spread for p in self.equilibria],
                               "metres_per_volt": self.metres_per_volt}}


def analyse(equilibria: list[Equilibrium], steps: list[list[DriveStep]], rig: RigParameters, *, metres_per_volt: float,
            lag_s: float = AMPLITUDE_TIME_CONSTANT_S, degree: int = FIT_DEGREE) -> Identification:
    """K at each equilibrium by eq. (16) with |a| = ``metres_per_volt`` V, its fit of the form of eq. (17), and
    the damping factor over eq. (6) at each step height with its 95 % interval."""
    data = EquilibriumData(np.array([p.height for p in equilibria]),
                           metres_per_volt * np.array([p.voltage for p in equilibria]), np.zeros(len(equilibria)))
    calibration = fit_calibration(rig, data, degree)
    fits = [[fit_step(s.times, s.heights, metres_per_volt * s.voltage_before, metres_per_volt * s.voltage_after, rig,
                      lag_s)
             for s in at_height] for at_height in steps]
    return Identification(calibration, equilibria, damping_table(fits), rig, fits, steps, metres_per_volt)
