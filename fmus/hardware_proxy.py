"""HardwareProxy FMU: the rig itself in the loop, over a serial port (docs/hil.md, docs/protocol.md).

It stands where fig7_slow has the ResonanceTracker, the Plant and the SensorChain: the rig does their
work in hardware. A thin adapter over :class:`nfal.hil.link.RigLink`:

* At the end of initialisation it opens ``port`` (any pyserial URL), says HELLO and waits for the rig's
  HELLO_ACK and a first measurement (``connect_timeout``), so its first outputs are measured ones.
  The rig's sample period must match ``sample_rate`` (1 %).
* ``doStep(t, dt)`` writes DRIVE(``drive_voltage``) for [t, t + dt], takes in what the port holds
  without waiting (:meth:`RigLink.poll`) and publishes the newest measurement: the step never waits for
  one. Outputs come from that measurement alone: no dependencies on the input.
* Missed samples are counted by the wall clock: ``samples_missed`` = the age of the newest sample times
  ``sample_rate`` (a master catching up after a stall of its own steps in a burst that finds nothing new,
  without the rig having missed anything). Above ``max_missed_samples`` the step fails with the reason
  logged (the link's last error): the proxy never makes a measurement up; a held value is flagged by
  ``fresh`` = false and a growing ``samples_missed``. pythonfmu reports a failing step as fmi2Fatal
  (docs/cosimulation.md).
* With ``lockstep`` the step waits (up to ``connect_timeout``) for the measurement that reports its DRIVE applied:
  the loop runs on the rig's clock, and missed samples are counted in rig time (the ticks between two answers, less
  one): a host paused between the answer and its step is no rig's silence. Against ``nfal rig-emulator
  --lockstep``, whose ticks wait for each DRIVE, the loop is then the same whatever the machine's load and however
  the master is paced (for tests and debugging; on a rig on its own clock the step takes up to a sample period).
* A sample flagged WATCHDOG_TRIPPED fails the step too: the rig had no DRIVE for its watchdog time (the
  host stalled), ramps the drive down and ignores DRIVE until a new session, so the loop is open and the
  run can no longer mean anything. (A reconnection's HELLO clears the trip, so a link that comes back
  within ``max_missed_samples`` resumes.)
* From the end of initialisation to ``terminate`` the process runs under the real-time discipline
  (:func:`nfal.realtime.realtime_section`: the garbage collector frozen and run right after each DRIVE, in any master,
  libcosim's and the C hosts' too).
* ``drive_gap_*``: the host time between DRIVE commands leaving (:attr:`RigLink.drive_gaps`): the margin to the
  rig's watchdog, as ``nfal run`` reports it.
* ``terminate`` sends STOP (the rig ramps the drive down) and closes the port; a failing step closes it
  too, and the rig's watchdog ramps the drive down by itself.

The rig cannot be rewound: the FMU cannot restore an FMU state (built with canGetAndSetFMUstate false).
"""

from __future__ import annotations

import contextlib

from nfal.errors import FmuStateError, InvalidParameterError, LinkError, require_positive
from nfal.fmus.base import DefaultExperiment, NfalSlave
from nfal.hil.link import RigLink
from nfal.hil.protocol import StatusFlags
from nfal.models.table2 import SAMPLING_RATE_HZ
from nfal.realtime import realtime_section

_LOCKED, _RESTING, _TRIPPED, _OUT_OF_RANGE = (int(flag) for flag in (
    StatusFlags.PLL_LOCKED, StatusFlags.RESTING, StatusFlags.WATCHDOG_TRIPPED, StatusFlags.SENSOR_OUT_OF_RANGE))
#: Relative mismatch allowed between ``sample_rate`` and the rig's announced sample period.
RATE_TOLERANCE = 0.01
#: Steps between updates of the drive-gap percentiles (a histogram scan; the maximum is updated every step).
GAP_PERCENTILES_EVERY = 100


class HardwareProxy(NfalSlave):
    """Drive voltage out to the rig, the rig's measurements in, over the nfal rig protocol."""

    CAN_SAVE_STATE = False  # the rig cannot be rewound

    description = ("Hardware proxy: sends the drive voltage to the levitation rig over a serial port and outputs its "
                   "measured height, drive frequency, lock and the link's health (nfal rig protocol v1)")
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=1.0, step_size=5e-4)

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.add_input("drive_voltage", 0.0, unit="V", description="drive voltage amplitude V for the rig (>= 0)")
        self.add_output("measured_height", unit="m", description="the rig's measured clearance (newest sample)")
        self.add_output("drive_frequency", unit="Hz", description="drive frequency set by the rig's PLL")
        self.add_output("applied_voltage", unit="V",
                        description="voltage the rig applied (after its limit and watchdog)")
        self.add_output("locked", kind=bool, description="the rig's PLL is locked")
        self.add_output("resting", kind=bool, description="the object rests on the driving surface")
        self.add_output("watchdog_tripped", kind=bool, description="the rig's watchdog has ramped the drive down")
        self.add_output("sensor_out_of_range", kind=bool, description="the rig's height sensor is saturated: "
                        "measured_height is its range limit")
        self.add_output("rig_time", unit="s", description="the rig's clock at the sample")
        self.add_output("measurement_age", unit="s",
                        description="host time since the sample arrived, at the step's end")
        self.add_output("fresh", kind=bool, description="a new sample arrived during the last step")
        self.add_output("link_ok", kind=bool, description="the session with the rig is up")
        self.add_output("samples_missed", kind=int, description="rig samples due since the newest one arrived "
                        "(measurement_age x sample_rate, rounded down; with lockstep, the rig's ticks between two "
                        "answers less one)")
        self.add_output("frames_dropped", kind=int, description="frames received and dropped (corrupt, truncated, "
                        "oversized, unknown, out of order)")
        self.add_output("frames_lost", kind=int, description="frames missing from the rig's sequence")
        self.add_output("rig_faults", kind=int, description="FAULT reports received from the rig")
        self.add_output("reconnects", kind=int, description="sessions re-established after a lost link")
        self.add_output("drive_gap_max", unit="s", description="longest host time between two DRIVE commands so far "
                        "(the margin to the rig's watchdog)")
        self.add_output("drive_gap_p50", unit="s", description="median host time between two DRIVE commands "
                        f"(updated every {GAP_PERCENTILES_EVERY} steps)")
        self.add_output("drive_gap_p99", unit="s", description="99th percentile of the host time between two DRIVE "
                        f"commands (updated every {GAP_PERCENTILES_EVERY} steps)")
        self.add_parameter("port", "", description="the rig's serial port: a device path, a pty, socket://host:port, "
                           "or any pyserial URL")
        self.add_parameter("baud_rate", 2_000_000, description="line rate [baud] (ignored by ptys and sockets)")
        self.add_parameter("connect_timeout", 2.0, unit="s",
                           description="wait for the rig's HELLO_ACK and first sample")
        self.add_parameter("max_missed_samples", 20, description="samples the rig may miss in a row (by the wall "
                           "clock) before the step fails (20 = 10 ms at 2 kHz)")
        self.add_parameter("lockstep", False, description="each step waits for the rig's measurement that reports "
                           "its DRIVE applied (up to connect_timeout): against nfal rig-emulator --lockstep a loop "
                           "that does not depend on the machine's load")
        self.add_parameter("reconnect", True, description="reopen the port and say HELLO again after a lost link")
        self.add_parameter("sample_rate", SAMPLING_RATE_HZ, unit="Hz",
                           description="the rig's sample rate, checked at connection")
        self._link: RigLink | None = None
        self._settings: tuple | None = None
        self._seen = 0
        self._steps = 0
        self._answered_at: float | None = None  # lockstep: the rig time of the last answer
        self._realtime = contextlib.ExitStack()
        self._collector = None

    # --- the session ------------------------------------------------------------------------------
    def setup(self) -> None:
        settings = (str(self.port), int(self.baud_rate), float(self.connect_timeout), bool(self.reconnect),
                    float(self.sample_rate))
        if int(self.max_missed_samples) < 1:
            raise InvalidParameterError("max_missed_samples", self.max_missed_samples, "a whole number >= 1")
        if self._link is not None and settings == self._settings:
            return  # a provisional setup in initialisation mode already opened it
        self._close()
        require_positive("sample_rate", self.sample_rate)
        link = RigLink(settings[0], baudrate=settings[1], connect_timeout_s=settings[2], reconnect=settings[3],
                       reader_thread=False)
        ack = link.open()
        try:
            period = ack.sample_period_us * 1e-6
            if abs(period * self.sample_rate - 1.0) > RATE_TOLERANCE:
                raise LinkError(f"{link.url}: the rig samples every {period * 1e6:g} us, not at sample_rate = "
                                f"{self.sample_rate:g} Hz")
            if not link.wait_until(lambda: link.latest() is not None, self.connect_timeout):
                raise LinkError(f"{link.url}: the rig answered HELLO but sent no measurement within "
                                f"{self.connect_timeout:g} s")
        except BaseException:
            link.close()
            raise
        self._link, self._settings = link, settings
        # the real-time discipline (nfal.realtime) from here to the end of the session, whatever master steps the proxy
        self._collector = self._realtime.enter_context(realtime_section())
        self._publish(link.latest(), fresh=True)
        self.samples_missed = 0
        self._answered_at = None

    @property
    def link(self) -> RigLink | None:
        """The session opened at the end of initialisation (None before, and once closed): for a loop that drives the
        rig itself while the proxy holds the session (the compiled loop, docs/hil.md)."""
        return self._link

    def _publish(self, sample, *, fresh: bool) -> None:
        link = self._link
        measurement = sample.measurement
        self.measured_height = measurement.height
        self.drive_frequency = measurement.drive_frequency
        self.applied_voltage = measurement.drive_voltage
        status = measurement.status  # plain int tests: enum flag arithmetic costs microseconds per step
        self.locked = bool(status & _LOCKED)
        self.resting = bool(status & _RESTING)
        self.watchdog_tripped = bool(status & _TRIPPED)
        self.sensor_out_of_range = bool(status & _OUT_OF_RANGE)
        self.rig_time = measurement.timestamp_us * 1e-6
        self.measurement_age = link.clock() - sample.arrival_s
        self.fresh = fresh
        self.link_ok = link.connected
        counters = link.decoder.counters
        self.frames_dropped, self.frames_lost = counters.dropped, counters.lost
        self.rig_faults, self.reconnects = link.counters.faults, link.counters.reconnects
        gaps = link.drive_gaps
        self.drive_gap_max = gaps.maximum
        if self._steps % GAP_PERCENTILES_EVERY == 0:
            self.drive_gap_p50, self.drive_gap_p99 = gaps.percentile(50), gaps.percentile(99)
        self._steps += 1
        self._seen = sample.count

    def step(self, current_time: float, step_size: float) -> None:
        link = self._link
        voltage = float(self.drive_voltage)
        if not voltage >= 0.0:
            raise InvalidParameterError("drive_voltage", voltage, "a voltage >= 0 V")
        link.send_drive(voltage)
        self._collector.safe_point()  # right after the DRIVE left: the most slack before the next one
        if self.lockstep:
            self._await_answer(link, current_time)
        else:
            link.poll()  # what has arrived, without waiting
        sample = link.latest()
        self._publish(sample, fresh=sample.count != self._seen)
        if self.lockstep:  # in rig time: the ticks between two answers, less one (0 while the rig waits for each DRIVE)
            previous, self._answered_at = self._answered_at, self.rig_time
            ticks = 1 if previous is None else round((self.rig_time - previous) * self.sample_rate)
            self.samples_missed = max(0, ticks - 1)
            silence_s = self.samples_missed / self.sample_rate
        else:
            # by the wall clock, not by steps: a master catching up after a stall of its own steps in a burst,
            # and those steps find nothing new although the rig has not missed a sample
            self.samples_missed = int(self.measurement_age * self.sample_rate)
            silence_s = self.measurement_age
        if self.watchdog_tripped:
            self._close(stop=False)
            raise LinkError(f"{self.port}: the rig's watchdog has tripped (sample at rig time {self.rig_time:.4f} s): "
                            f"no DRIVE reached it for {link.rig.watchdog_timeout_us * 1e-3:g} ms, as when the host "
                            "stalls; the rig ramps the drive down and ignores DRIVE until a new session: the loop is "
                            "open")
        if self.samples_missed > self.max_missed_samples:
            reason = link.last_error or "no error on the port: the rig went silent"
            self._close(stop=False)
            raise LinkError(f"{self.port}: no measurement from the rig for {silence_s * 1e3:.1f} ms "
                            f"({self.samples_missed} samples, limit max_missed_samples = "
                            f"{self.max_missed_samples}): link lost ({reason}); the last sample is from rig time "
                            f"{self.rig_time:.4f} s")

    def _await_answer(self, link: RigLink, current_time: float) -> None:
        """Lockstep: wait for the measurement that reports this step's DRIVE applied (up to connect_timeout)."""
        if not link.wait_applied(self.connect_timeout):
            self._close(stop=False)
            raise LinkError(f"{self.port}: lockstep: the rig did not report the DRIVE of t = {current_time:g} s "
                            f"applied within connect_timeout = {self.connect_timeout:g} s ("
                            f"{link.last_error or 'no error on the port: a frame lost on the wire?'}); lockstep needs "
                            "every frame, so faults such as the emulator's --drop belong to runs on the wall clock")

    def terminate(self) -> None:
        self._close()

    def _close(self, *, stop: bool = True) -> None:
        link, self._link, self._settings = self._link, None, None
        if link is not None:
            link.close(stop=stop)
            self.link_ok = False
        self._realtime.close()

    def __del__(self) -> None:
        link = getattr(self, "_link", None)
        if link is not None:
            link.close(stop=False)
        realtime = getattr(self, "_realtime", None)
        if realtime is not None:
            realtime.close()  # the collector back as it was, also for an instance freed without terminate

    # --- FMU state: hardware cannot be rewound --------------------------------------------------------
    def get_internal_state(self) -> dict:
        raise FmuStateError("the HardwareProxy cannot save an FMU state: the rig cannot be rewound")

    def set_internal_state(self, state: dict) -> None:
        raise FmuStateError("the HardwareProxy cannot restore an FMU state: the rig cannot be rewound")
