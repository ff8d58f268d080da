"""A rig identified over its port, end to end (what ``nfal identify`` runs): the experiments in a real-time section
with the raw samples streamed to disk, the fits, the calibration file with its provenance, and the figure.

The parts are :mod:`nfal.apps.rig_io` (the link), :mod:`nfal.apps.sample_recorder`,
:mod:`nfal.apps.rig_experiments` and :mod:`nfal.apps.rig_analysis`; this module runs them in order and keeps the
rig safe on the way: any fault or stop signal ramps the drive down, sends STOP and keeps every sample.
"""

from __future__ import annotations

import contextlib
import datetime
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from nfal import __version__
from nfal.apps.figures.identify import plot_identification
from nfal.apps.rig_analysis import Identification, analyse
from nfal.apps.rig_experiments import Experiments, move_law, recorder_capacity
from nfal.apps.rig_io import LinkRig
from nfal.apps.sample_recorder import FREQUENCY, SampleRecorder
from nfal.errors import ConvergenceError, DataFormatError, ExperimentError, InvalidParameterError
from nfal.models.identification import IdentificationPlan
from nfal.models.pid_design import design_schedule
from nfal.models.rig import RigParameters
from nfal.models.stability import realizable_schedule
from nfal.orchestration.interrupts import deferred_interrupts
from nfal.realtime import BackgroundWriter, realtime_section


@dataclass(frozen=True)
class IdentifySettings:
    """What an identification needs besides its plan (each checked by the caller)."""

    port: str
    #: The calibration file; the raw samples and the figure go beside it (:func:`output_paths`).
    out: Path
    rig: RigParameters
    metres_per_volt: float
    max_voltage: float
    #: The transducer's amplitude lag 2Q/omega_r [s] in the step fits.
    lag_s: float
    connect_timeout_s: float
    max_silence_s: float


@dataclass(frozen=True)
class IdentifiedRig:
    """What :func:`identify_rig` measured and wrote."""

    result: Identification
    samples: int
    rig_time_s: float
    #: The stall monitor's figures (gaps between DRIVE commands, lateness, collector pauses) and the rig's watchdog.
    timing: dict
    calibration: Path
    raw: Path
    figure: Path


def output_paths(out: Path) -> tuple[Path, Path, Path]:
    """The calibration file, the raw samples' CSV and the figure of an identification written to ``out``."""
    return out, out.with_name(out.stem + "-raw.csv"), out.with_suffix(".png")


def drive_gap_margin(timing: dict) -> str:
    """One line: the gaps between DRIVE commands, to set against the rig's watchdog."""
    gaps = timing["drive_gaps"]
    return (f"gaps between DRIVE commands: p50 {gaps['p50_s'] * 1e3:.2f} ms, p99 {gaps['p99_s'] * 1e3:.2f} ms, "
            f"max {gaps['max_s'] * 1e3:.2f} ms")


def identify_rig(plan: IdentificationPlan, settings: IdentifySettings, *,
                 on_hold: Callable[[], None] = lambda: None) -> IdentifiedRig:
    """Run ``plan`` on the rig at ``settings.port`` and write the calibration file, the raw CSV and the figure;
    ``on_hold`` is called after each hold (progress). An :class:`~nfal.errors.ExperimentError` or a stop signal
    (KeyboardInterrupt) ends it with the drive ramped down, STOP sent and every sample on disk, and says so."""
    capacity = recorder_capacity(plan)  # a plan whose samples cannot be held is refused before anything opens
    _, raw, figure = output_paths(settings.out)
    schedule = realizable_schedule(design_schedule())  # before the port opens: the rig streams from HELLO_ACK on
    try:
        stream = open(raw, "w", encoding="utf-8", newline="")  # noqa: SIM115 - closed below, after the experiments
    except OSError as exc:
        raise InvalidParameterError("--out", str(settings.out), f"a writable place for {raw.name}: {exc}") from None
    # the real-time section (nfal.realtime) starts before the port opens: its set-up (a full collection, 0.05-0.2 s)
    # must not leave a backlog of the rig's stream; SIGINT, SIGTERM and SIGHUP are taken at the next exchange
    # the samples reach the disk through a thread (nfal.realtime.BackgroundWriter): the loop never waits for it
    with (contextlib.closing(BackgroundWriter(stream)) as writer, deferred_interrupts() as stop_request,
          realtime_section() as collector):
        recorder = SampleRecorder(writer, capacity)  # at 2 kHz (it grows for a faster rig)
        try:
            link = LinkRig(settings.port, connect_timeout_s=settings.connect_timeout_s,
                           max_silence_s=settings.max_silence_s)
        except BaseException:
            writer.close()
            raw.unlink(missing_ok=True)  # nothing measured: no empty file left behind
            raise
        link.safe_point = collector.safe_point
        hello, max_voltage = link.hello, min(settings.max_voltage, link.hello.max_drive_voltage)
        law = move_law(plan, metres_per_volt=settings.metres_per_volt, max_voltage=max_voltage, schedule=schedule)
        experiments = Experiments(link, plan, recorder, metres_per_volt=settings.metres_per_volt,
                                  max_voltage=max_voltage, law=law, on_hold=on_hold, stop_request=stop_request)
        collector.settle()  # the set-up's objects frozen too, before the first DRIVE
        equilibria, steps = _run(experiments, link, raw)
        timing = {**link.timing(), **collector.report(), "rig_watchdog_s": hello.watchdog_timeout_us * 1e-6}
    try:
        result = analyse(equilibria, steps, settings.rig, metres_per_volt=settings.metres_per_volt,
                         lag_s=settings.lag_s)
    except (ConvergenceError, DataFormatError, InvalidParameterError) as exc:
        raise ExperimentError(f"the measurements cannot be fitted: {exc}; the data are in {raw}") from None
    provenance = _provenance(plan, settings, hello, recorder, raw, timing)
    settings.out.write_text(json.dumps(result.document(provenance), indent=2) + "\n", encoding="utf-8")
    plot_identification(figure, result, settings.rig, settings.lag_s)
    return IdentifiedRig(result, recorder.count, recorder.duration_s, timing, settings.out, raw, figure)


def _run(experiments: Experiments, link: LinkRig, raw: Path):
    """The experiments; on any fault or stop signal the drive ramps down, STOP goes out and the message says where
    the data are and what margin the loop kept to the rig's watchdog."""
    try:
        equilibria = experiments.equilibria()
        steps = experiments.damping_steps()
    except (ExperimentError, KeyboardInterrupt) as exc:
        ramped = experiments.ramp_down()
        link.close()
        stopped = ("the drive ramped down; STOP sent" if ramped
                   else "no link to ramp the drive down: the rig's watchdog does")
        kept = f"every sample so far is in {raw} ({experiments.recorder.count} samples)"
        what = f"{str(exc) or 'interrupted'}; {stopped}; {kept}; {drive_gap_margin(link.timing())}"
        if isinstance(exc, KeyboardInterrupt):
            exc.args = (what,)  # the same interruption (its signal_number gives the exit code), told whole
            raise
        raise ExperimentError(what) from None
    experiments.ramp_down()
    link.close()
    return equilibria, steps


def _provenance(plan: IdentificationPlan, settings: IdentifySettings, hello, recorder: SampleRecorder, raw: Path,
                timing: dict) -> dict:
    return {"date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "port": settings.port,
            "firmware_version": f"nfal rig protocol {hello.protocol_version} "
                                "(the protocol reports no firmware version)",
            "raw_data": raw.name, "nfal_version": __version__, "rig_time_s": recorder.duration_s,
            "sample_period_s": hello.sample_period_us * 1e-6, "watchdog_s": hello.watchdog_timeout_us * 1e-6,
            "rig_max_drive_voltage_v": hello.max_drive_voltage, "max_voltage_v": settings.max_voltage,
            "metres_per_volt": settings.metres_per_volt, "amplitude_time_constant_s": settings.lag_s,
            "drive_frequency_hz_median": float(np.median(recorder.column(FREQUENCY))),
            "rig": {"mass_kg": settings.rig.mass, "radius_m": settings.rig.radius},
            "step_fraction": plan.step_fraction, "steps_per_height": plan.steps, "realtime": timing}
