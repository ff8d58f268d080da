"""One session of the rig emulator, as ``nfal rig-emulator`` runs it: the rig structure opened, its firmware (the
Python one, or the C one as a process of its own) behind a port, the :class:`~nfal.apps.rig_emulator.Emulator` run
until its duration or a stop signal, and its report."""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from nfal.apps.rig_emulator import Disconnection, Emulator, EmulatorReport
from nfal.apps.rig_model import open_rig
from nfal.hil.faults import FaultSettings
from nfal.hil.firmware import RigTiming
from nfal.hil.ports import PtyPort, UrlPort
from nfal.orchestration.interrupts import STOP_SIGNALS
from nfal.orchestration.pacing import realtime_priority

FIRMWARE_NAMES = {"python": "Python firmware", "c": "C firmware (host build)",
                  "qemu": "C firmware in QEMU mps2-an386"}


@dataclass(frozen=True)
class EmulatorSettings:
    """A session's settings, each checked by the caller."""

    #: The rig structure (.ssp, .ssd or folder) whose blocks play the hardware, and overrides of its parameters.
    truth: Path
    parameters: dict[str, str]
    timing: RigTiming
    #: "pty" (a new pseudo-terminal, at ``link`` or a new name) or a pyserial URL.
    port: str = "pty"
    link: str | None = None
    #: python, c or qemu (:data:`FIRMWARE_NAMES`); c and qemu need a pty and no faults.
    firmware: str = "python"
    lockstep: bool = False
    faults: FaultSettings = FaultSettings()
    disconnection: Disconnection | None = None
    #: Every measurement of a session, with the applied voltage and the true height (CSV).
    record: Path | None = None
    #: Seconds of the run; None: until a stop signal.
    duration_s: float | None = None
    #: SCHED_FIFO priority of the paced ticks (None: the process's own scheduling).
    rt_priority: int | None = None


def serve_rig(settings: EmulatorSettings, truth_name: str, say: Callable[[str], None]) -> EmulatorReport:
    """Play the rig on its port until ``settings.duration_s`` or SIGINT, SIGTERM or SIGHUP (each ends the run after
    the current tick, so the report is whole and the port's link removed). ``say`` gets the port's path first, then
    a line on the rig and one per event; ``truth_name`` names the truth in that line."""
    timing = settings.timing
    with open_rig(settings.truth, timing.sample_period_s, settings.parameters) as model, \
            contextlib.ExitStack() as stack:
        firmware = None
        if settings.firmware == "python":
            port = PtyPort(settings.link) if settings.port == "pty" else UrlPort(settings.port)
        else:
            # on use: C firmware only
            from nfal.hil.plant_channel import ExternalFirmware, FirmwarePort, FirmwareProcess

            # lockstep: the host's bytes through the emulator (which holds them until a DRIVE), else the firmware's
            # own serial line
            process = stack.enter_context(FirmwareProcess(settings.firmware, serial=not settings.lockstep))
            firmware = ExternalFirmware(process, timing, tunnel=settings.lockstep)
            port = PtyPort(settings.link) if settings.lockstep else FirmwarePort(process, settings.link)
        stack.callback(port.close)
        record = stack.enter_context(open(settings.record, "w", encoding="utf-8")) if settings.record else None
        emulator = Emulator(port, model, timing=timing, faults=settings.faults, disconnection=settings.disconnection,
                            on_event=say, record=record, firmware=firmware, lockstep=settings.lockstep)
        # from the moment the port is announced: whoever reads it may signal at once
        previous = {number: signal.signal(number, lambda *_: emulator.stop()) for number in STOP_SIGNALS}
        try:
            say(str(port.path))
            scheduling = "" if settings.rt_priority is None else f", SCHED_FIFO priority {settings.rt_priority}"
            say(f"rig emulator: truth {truth_name}, {FIRMWARE_NAMES[settings.firmware]}, "
                f"{1 / timing.sample_period_s:g} Hz{', lockstep' if settings.lockstep else ''}, "
                f"watchdog {timing.watchdog_timeout_s * 1e3:g} ms{scheduling}; Ctrl-C to stop")
            with realtime_priority(settings.rt_priority):  # the paced ticks only
                report = emulator.run(settings.duration_s)
            if firmware is not None:  # its frames went out on its own line: it counted them
                report.frames_sent = firmware.channel.counters()["tx_frames"]
        finally:
            for number, handler in previous.items():
                signal.signal(number, handler)
    return report
