"""``nfal run --compiled``: a Controller -> HardwareProxy structure (``ssp/fig7_hil.ssd``) run by the compiled 2 kHz
loop (``firmware/loop/``, :mod:`.compiled_loop`) instead of the master, for a rig on its own clock (docs/hil.md,
"The compiled loop").

The two elements are set up by their own code, in this process: the Controller FMU's slave designs the law and its
bumpless start from the structure's parameters, the HardwareProxy's opens the session (HELLO, the rig's period
checked, the first measurement) and enters the real-time section. Then the loop takes over the port and the law on a
thread of its own, in C, without the GIL (ctypes releases it for the call): it writes each DRIVE, takes in the rig's
frames and runs the law, and records the rows the two FMUs would output into a ring. This thread drains the ring into
``results.csv`` (the master's columns, named and ordered as a master run writes them), turns a stop signal into the
loop's ``stop``, and afterwards hands the port back to the proxy, which sends STOP and closes it. ``summary.json``
and the plot, metrics and checks follow as for any run (:func:`~nfal.orchestration.run.finish_run`).

With ``proxy.lockstep`` each step waits for the rig's answer, as the HardwareProxy's does, and the loop is released
at once instead of on the clock: against ``nfal rig-emulator --lockstep`` its rows are the master's run's to the bit
(the wall-clock columns aside: ``measurement_age``, the drive gaps), whatever the machine's load (the tests' check).

What differs from the master's run of the same structure: no reconnection (a lost link ends the run, as
``max_missed_samples`` would); one law sample per communication step (the step must be the Controller's sample
period); a law with a feedforward path is refused (the compiled law does not carry the design model).
"""

from __future__ import annotations

import ctypes
import dataclasses
import datetime
import os
import sys
import tempfile
import threading
import time
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from tqdm import tqdm

from nfal.apps.compiled_loop import (DOUBLES, ENDS, ROW, CompiledLaw, LawState, LinkState, LoopConfig, Row, Shared,
                                     library)
from nfal.errors import InvalidParameterError, LinkError, SimulationError, UnsupportedFeatureError
from nfal.fmus.controller import Controller
from nfal.fmus.hardware_proxy import GAP_PERCENTILES_EVERY, HardwareProxy
from nfal.hil.protocol import StatusFlags
from nfal.models.control_law import SaturationWatch
from nfal.orchestration import read_ssp
from nfal.orchestration.interrupts import Interrupted, deferred_interrupts
from nfal.orchestration.master import Master
from nfal.orchestration.pacing import ReleaseStats, require_realtime_priority
from nfal.orchestration.resolve import resolve
from nfal.orchestration.results import CsvWriter, write_summary
from nfal.orchestration.run import (MAX_STEPS, RESULTS_CSV, SUMMARY_JSON, RunResult, claim_results_folder,
                                    experiment_steps, finish_run, loop_summary, opening_summary)
from nfal.orchestration.signals import as_signal
from nfal.realtime import LatencyStats

#: Rows the ring holds (a power of two): 65 s at 2 kHz that the recorder may fall behind before the loop ends.
RING_ROWS = 1 << 17
#: How often the recorder drains the ring [s].
DRAIN_PAUSE_S = 0.05
#: Before each release the loop sleeps until this close, then spins [s]: most of the period, so that its vCPU hardly
#: idles (a hypervisor is slow to give an idle vCPU back: bench/machine_floor.py, docs/hil.md "This machine's floor"),
#: and not all of it, so that the kernel's real-time throttling (95 % of a CPU) never stops it under SCHED_FIFO.
SPIN_S = 4e-4
#: The FMUs the loop stands in for, by model identifier, and the connections it makes between them.
ROLES = {"Controller": Controller, "HardwareProxy": HardwareProxy}
WIRING = {("Controller", "drive_voltage", "HardwareProxy", "drive_voltage"),
          ("HardwareProxy", "measured_height", "Controller", "measured_height")}


def run_compiled(structure: str | os.PathLike, *, reference, parameters: Mapping[str, object] | None = None,
                 start_time: float | None = None, stop_time: float | None = None, step_size: float | None = None,
                 out_dir: str | os.PathLike | None = None, rt_priority: int | None = None, overwrite: bool = False,
                 max_steps: int | None = None, progress: bool | None = None, plot=None, metrics=None,
                 checks=None) -> RunResult:
    """Run ``structure`` (a Controller and a HardwareProxy wired as ``fig7_hil``) with the compiled loop, the
    Controller's reference driven by ``reference`` (a signal of time). Arguments and result as
    :func:`~nfal.orchestration.run.run_structure`'s; ``rt_priority``: the loop's thread under SCHED_FIFO."""
    started_at = datetime.datetime.now().astimezone().isoformat(timespec="seconds")
    if rt_priority is not None:
        require_realtime_priority(rt_priority)
    with read_ssp(structure) as read:
        system = resolve(read, parameters)
        elements = _pair(system)
        start, step, steps = experiment_steps(read.default_experiment, start_time, stop_time, step_size,
                                              MAX_STEPS if max_steps is None else max_steps)
        inputs = {f"{elements['Controller'].name}.reference": reference}
        master = Master(system, step_size=step, inputs=inputs)  # the columns, as a master run of it writes them
        references = _references(as_signal(reference), start, step, steps)
        out = Path(out_dir) if out_dir is not None else Path(tempfile.mkdtemp(prefix="nfal-run-"))
        claim_results_folder(out, overwrite)
        summary = opening_summary(structure, system, master, "compiled", start, step, steps, started_at, inputs,
                                  parameters, rt_priority)
        summary_path = write_summary(out / SUMMARY_JSON, summary)
        writer = CsvWriter(out / RESULTS_CSV, master.columns)
        show = progress if progress is not None else sys.stderr.isatty()
        with tqdm(total=steps, disable=not show, file=sys.stderr, unit="step", desc=system.name, leave=False,
                  mininterval=0.25) as bar:
            outcome = _run(elements, master.columns, writer, references, start, step, steps, rt_priority, bar)
        summary.update(outcome.summary(start, step, writer.rows))
        return finish_run(RunResult(out, out / RESULTS_CSV, summary_path, None, summary), outcome.error, plot=plot,
                          metrics=metrics, checks=checks, title=f"{system.name} (compiled loop, {step:g} s)")


def _pair(system) -> dict:
    """The structure's elements by role; refused unless it is exactly a Controller and a HardwareProxy wired as
    fig7_hil."""
    roles = {element.model_description.coSimulation.modelIdentifier: element for element in system.elements}
    names = {element.name: role for role, element in roles.items()}
    wiring = {(names.get(link.source.element), link.source.name, names.get(link.target.element), link.target.name)
              for link in system.links}
    if set(roles) != set(ROLES) or len(system.elements) != 2 or wiring != WIRING:
        raise UnsupportedFeatureError(
            f"{system.name}: the compiled loop runs a Controller and a HardwareProxy wired as fig7_hil "
            "(Controller.drive_voltage -> proxy.drive_voltage, proxy.measured_height -> Controller.measured_height), "
            f"not elements {sorted(names.values())} with {len(system.links)} connections; run it without --compiled")
    return roles


def _references(signal, start: float, step: float, steps: int) -> np.ndarray:
    """The Controller's reference at every row, at the times the master gives it."""
    return np.array([float(signal(start + k * step)) for k in range(steps + 1)])


def _slaves(elements: dict, reference: float, start: float) -> dict:
    """Both slaves made and in initialisation mode, their parameters set; the Controller's initialisation ended (its
    law designed), the proxy's not yet (it opens the session)."""
    slaves = {}
    for role, element in elements.items():
        slave = slaves[role] = ROLES[role](instance_name=element.name)
        for name, value in element.start_values.items():
            setattr(slave, name, value)
        slave.setup_experiment(start)
        slave.enter_initialization_mode()
    slaves["Controller"].reference = reference
    slaves["Controller"].exit_initialization_mode()
    return slaves


@dataclasses.dataclass
class _Outcome:
    """What the loop did (as the master's run reports it)."""

    error: BaseException | None = None
    steps_done: int = 0
    init_time_s: float = 0.0
    loop_time_s: float = 0.0
    wall_time_s: float = 0.0
    realtime: dict | None = None

    def summary(self, start: float, step: float, rows: int) -> dict:
        return {**loop_summary(self.error, self.steps_done, start, step, rows, self.wall_time_s, self.init_time_s,
                               self.loop_time_s),
                "do_step_wall_time_s": None, "exchange_and_record_us_per_step": None, "timing": {},
                "realtime": self.realtime}


def _run(elements: dict, columns, writer: CsvWriter, references: np.ndarray, start: float, step: float, steps: int,
         rt_priority: int | None, bar) -> _Outcome:
    """Set up, run the loop on its thread and drain it; every error is caught into the outcome (the CSV closed,
    every row kept)."""
    outcome, wall_start, slaves, loop = _Outcome(), time.perf_counter(), {}, None
    try:
        with deferred_interrupts() as stop_request:
            slaves = _slaves(elements, float(references[0]), start)
            loop = _Loop(slaves["Controller"], references, step, steps, rt_priority)  # ready before the session opens
            proxy = slaves["HardwareProxy"]
            proxy.exit_initialization_mode()  # the session: HELLO, HELLO_ACK, the first measurement
            recorder = _Recorder(columns, elements, slaves, start, step, proxy.link.counters.reconnects)
            outcome.init_time_s = time.perf_counter() - wall_start
            loop.start(proxy)
            while loop.running():
                recorder.timing.steal.sample()
                recorder.write(loop.rows(), writer)
                bar.update(loop.shared.steps_done - bar.n)
                if stop_request.signal_number is not None:
                    loop.shared.stop = 1
                time.sleep(DRAIN_PAUSE_S)
            recorder.timing.steal.sample()
            recorder.write(loop.rows(), writer)
            outcome.steps_done = loop.shared.steps_done
            outcome.loop_time_s = loop.wall_time_s()
            if not proxy.lockstep:  # in lockstep the rig's answers pace the loop: no real-time report, as a master's
                outcome.realtime = recorder.timing.report(outcome.loop_time_s, rt_priority)
            outcome.error = loop.error(stop_request.signal_number, proxy)
    except BaseException as exc:  # noqa: BLE001 - recorded in the summary, then re-raised by finish_run
        outcome.error = exc
    finally:
        if loop is not None:
            loop.stop()  # (a second signal, or an error here) the port is the proxy's again before it closes it
        for slave in slaves.values():
            slave.terminate()  # the proxy sends STOP (the rig ramps the drive down) and closes the port
        try:
            writer.close()
        except OSError as exc:
            outcome.error = outcome.error or exc
    outcome.wall_time_s = time.perf_counter() - wall_start
    return outcome


class _Loop:
    """The compiled loop on its thread, with what it shares with Python."""

    def __init__(self, controller: Controller, references: np.ndarray, step: float, steps: int,
                 rt_priority: int | None) -> None:
        """Everything but the port, made before the session opens (a rig streams from then on)."""
        law = controller.law
        if abs(step - law.period_s) > 1e-9 * law.period_s:
            raise InvalidParameterError("step_size", step, f"the Controller's sample period {law.period_s:g} s: the "
                                        "compiled loop runs one sample of the law per step")
        library()  # built (make) and loaded now
        self.law, self.law_state = CompiledLaw(law), LawState.of(controller.law_state)
        self.metres_per_volt = float(controller.metres_per_volt)
        self.references = np.ascontiguousarray(references)
        self.ring = np.zeros(RING_ROWS, dtype=ROW)
        self.ring["reference_m"] = 0.0  # every page touched now (locked by the real-time section), not in the loop
        self.step, self.steps, self.rt_priority = step, steps, rt_priority
        self.shared = Shared()
        self._thread = threading.Thread(target=self._run, name="nfal-compiled-loop", daemon=True)
        self._end = None
        self._finished_at = None

    def start(self, proxy: HardwareProxy) -> None:
        """Take over the proxy's session and start."""
        self.link = link = proxy.link
        if link.descriptor is None:
            raise LinkError(f"{link.url}: the compiled loop needs a port with a file descriptor (a device, a pty, "
                            "socket://host:port)")
        link.drain()  # the stream since the session opened: the loop starts on the newest sample
        sample = link.latest()
        message, decoder = sample.measurement, link.decoder
        self.state = LinkState(message.height, message.drive_frequency, message.drive_voltage,
                               message.timestamp_us * 1e-6, sample.arrival_s, message.status, message.command_seq,
                               decoder.last_seq or 0, decoder.last_seq is not None, link.next_frame_seq,
                               decoder.mid_frame, sample.count, decoder.counters.dropped, decoder.counters.lost,
                               link.counters.faults)
        self.config = LoopConfig(link.descriptor, self.rt_priority or 0, self.steps, self.step, SPIN_S,
                                 self.metres_per_volt, float(proxy.sample_rate), int(proxy.max_missed_samples),
                                 bool(proxy.lockstep), float(proxy.connect_timeout),
                                 self.references.ctypes.data_as(DOUBLES), self.ring.ctypes.data_as(ctypes.POINTER(Row)),
                                 RING_ROWS)
        self._thread.start()

    def _run(self) -> None:
        try:
            self._end = library().nfal_loop_run(self.config, self.law.parameters, self.law_state, self.state,
                                                self.shared)
        finally:
            self._finished_at = library().nfal_loop_clock()
            self.link.next_frame_seq = self.state.next_drive_seq  # STOP follows the last DRIVE in order

    def running(self) -> bool:
        return self._thread.is_alive()

    def stop(self) -> None:
        """End the loop at its next step and wait for it (at once if it has ended or never started)."""
        self.shared.stop = 1
        if self._thread.is_alive():
            self._thread.join()

    def rows(self) -> np.ndarray:
        """The rows written since the last call (a copy), marked read."""
        shared = self.shared
        read, written = shared.rows_read, shared.rows_written
        rows = self.ring[np.arange(read, written) % RING_ROWS]
        shared.rows_read = written
        return rows

    def wall_time_s(self) -> float:
        return (self._finished_at or 0.0) - self.shared.start_s if self.shared.start_s else 0.0

    def error(self, signal_number: int | None, proxy) -> BaseException | None:
        """Why the loop ended, as the error the master's run would report (None: every step done)."""
        self._thread.join()
        end, state, shared = ENDS[self._end or 0], self.state, self.shared
        where = f"{proxy.port}: "
        if end == "done":
            return None
        if end == "stopped" and signal_number is not None:
            return Interrupted(signal_number)
        reasons = {
            "watchdog": f"the rig's watchdog has tripped (sample at rig time {state.rig_time_s:.4f} s): no DRIVE "
                        "reached it in time, as when the host stalls; the rig ramps the drive down",
            "silent": f"no measurement from the rig for more than {proxy.max_missed_samples} samples: link lost; the "
                      f"last sample is from rig time {state.rig_time_s:.4f} s",
            "law input": f"the Controller's law refused the measurement {state.height_m:g} m or the reference of "
                         f"step {shared.steps_done + 1}",
            "port": f"the port failed: {os.strerror(shared.error_number) if shared.error_number else 'closed'}",
            "restarted": "the rig opened a new session (HELLO_ACK) the loop did not ask for: it restarted",
            "ring full": f"the recorder fell {RING_ROWS} rows behind the loop",
            "setup": "the loop could not start (the port's flags, or SCHED_FIFO refused for its thread)",
            "no answer": f"lockstep: the rig did not report a DRIVE applied within connect_timeout = "
                         f"{proxy.connect_timeout:g} s",
        }
        return SimulationError(f"compiled loop: {where}{reasons.get(end, end)}, after {shared.steps_done} of "
                               f"{self.steps} steps")


def _row_field(name: str):
    return lambda rows, derived: rows[name]


def _derived_field(name: str):
    return lambda rows, derived: derived[name]


def _status_bit(flag: StatusFlags):
    bit = int(flag)
    return lambda rows, derived: [int(status & bit != 0) for status in rows["status"]]


#: (role, variable) -> its values for a chunk of rows (the ring's fields, the recorder's derived columns).
_FIELDS = {
    ("Controller", "reference"): _row_field("reference_m"),
    ("Controller", "drive_voltage"): _row_field("voltage_v"),
    ("Controller", "excitation_command"): _row_field("command_m"),
    ("Controller", "saturated_time"): _derived_field("saturated_time"),
    ("HardwareProxy", "measured_height"): _row_field("height_m"),
    ("HardwareProxy", "drive_frequency"): _row_field("drive_frequency_hz"),
    ("HardwareProxy", "applied_voltage"): _row_field("applied_voltage_v"),
    ("HardwareProxy", "locked"): _status_bit(StatusFlags.PLL_LOCKED),
    ("HardwareProxy", "resting"): _status_bit(StatusFlags.RESTING),
    ("HardwareProxy", "watchdog_tripped"): _status_bit(StatusFlags.WATCHDOG_TRIPPED),
    ("HardwareProxy", "sensor_out_of_range"): _status_bit(StatusFlags.SENSOR_OUT_OF_RANGE),
    ("HardwareProxy", "rig_time"): _row_field("rig_time_s"),
    ("HardwareProxy", "measurement_age"): _row_field("measurement_age_s"),
    ("HardwareProxy", "fresh"): _row_field("fresh"),
    ("HardwareProxy", "link_ok"): _derived_field("link_ok"),
    ("HardwareProxy", "samples_missed"): _row_field("samples_missed"),
    ("HardwareProxy", "frames_dropped"): _row_field("frames_dropped"),
    ("HardwareProxy", "frames_lost"): _row_field("frames_lost"),
    ("HardwareProxy", "rig_faults"): _row_field("rig_faults"),
    ("HardwareProxy", "reconnects"): _derived_field("reconnects"),
    **{("HardwareProxy", f"drive_gap_{name}"): _derived_field(f"drive_gap_{name}") for name in ("max", "p50", "p99")},
}


class _Recorder:
    """Rows of the ring -> the master's columns, with what the FMUs compute row after row: the saturation's duration
    (:class:`SaturationWatch`, as the Controller) and the drive gaps' statistics (as the proxy: the maximum every row,
    the percentiles every GAP_PERCENTILES_EVERY rows); and the loop's timing as the pacer reports it."""

    def __init__(self, columns, elements: dict, slaves: dict, start: float, step: float, reconnects: int) -> None:
        roles = {element.name: role for role, element in elements.items()}
        self.start, self.step, self.reconnects, self.next_row = start, step, reconnects, 0
        self.saturation = SaturationWatch(slaves["Controller"].law.max_excitation_m)
        self.gaps, self.drove, self.percentiles = LatencyStats(), False, (0.0, 0.0)
        self.timing = _Timing(step)
        self.fields = []
        for column in columns[1:]:
            element, _, variable = column.name.rpartition(".")
            field = _FIELDS.get((roles.get(element), variable))
            if field is None:
                raise UnsupportedFeatureError(f"the compiled loop does not record {column.name}: run without "
                                              "--compiled")
            self.fields.append(field)

    def write(self, chunk: np.ndarray, writer: CsvWriter) -> None:
        """Write the ring's records ``chunk`` as rows."""
        if not len(chunk):
            return
        first, self.next_row = self.next_row, self.next_row + len(chunk)
        rows = {name: chunk[name].tolist() for name in ROW.names}
        derived = self._derived(rows, first)
        times = [self.start + k * self.step for k in range(first, self.next_row)]
        for row in zip(times, *(field(rows, derived) for field in self.fields)):
            writer.write(row)
        self.timing.add(rows, first)

    def _derived(self, rows: dict, first: int) -> dict:
        count = len(rows["command_m"])
        derived = {name: [] for name in ("saturated_time", "drive_gap_max", "drive_gap_p50", "drive_gap_p99")}
        for k, command, sent, gap in zip(range(first, first + count), rows["command_m"], rows["drive_sent"],
                                         rows["drive_gap_s"]):
            now = self.start + k * self.step  # the master's time of row k
            # the Controller's own clock there: the previous step's time plus the step, as NfalSlave.do_step keeps it
            derived["saturated_time"].append(self.saturation.duration_s(now if k == 0 else
                                                                        self.start + (k - 1) * self.step + self.step))
            self.saturation.update(now, command)  # held from now on: the next row's duration counts it
            if sent:
                if self.drove:
                    self.gaps.add(gap)
                self.drove = True
            if k % GAP_PERCENTILES_EVERY == 0:
                self.percentiles = (self.gaps.percentile(50), self.gaps.percentile(99))
            derived["drive_gap_max"].append(self.gaps.maximum)
            derived["drive_gap_p50"].append(self.percentiles[0])
            derived["drive_gap_p99"].append(self.percentiles[1])
        derived["link_ok"], derived["reconnects"] = [1] * count, [self.reconnects] * count
        return derived


class _Timing(ReleaseStats):
    """The loop's steps as the master's pacer reports a paced run's."""

    def add(self, rows: dict, first: int) -> None:
        for k, late, duration in zip(range(first, first + len(rows["lateness_s"])), rows["lateness_s"],
                                     rows["duration_s"]):
            if k > 0:  # row 0 is the set-up's, before the first release
                self.released(late)
                self.finished(k - 1, duration, late + duration - self.period_s)

    def report(self, wall_time_s: float, rt_priority: int | None) -> dict:
        return {"engine": "compiled", "thread_rt_priority": rt_priority, **super().report(),
                "wall_time_s": wall_time_s}
