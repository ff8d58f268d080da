"""``nfal rig-emulator``: the rig, played in real time on a pty or a port, for hardware-in-the-loop runs (the session
is :func:`nfal.apps.rig_emulator_session.serve_rig`; this module checks the flags and prints)."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from nfal.apps.build import build_all
from nfal.apps.rig_emulator import Disconnection
from nfal.apps.rig_emulator_session import EmulatorSettings, serve_rig
from nfal.cli.commands import COMMANDS
from nfal.cli.commands.common import finite_float, output_file, positive_float, print_json, steal_text
from nfal.cli.commands.cosim import parse_parameter
from nfal.errors import InvalidParameterError
from nfal.hil.faults import FaultSettings
from nfal.hil.firmware import RigTiming
from nfal.orchestration.pacing import require_realtime_priority


def register(commands) -> None:
    emulator = commands.add_parser(
        "rig-emulator", help=COMMANDS["rig-emulator"].summary,
        description="Play the rig on a serial port in real time, speaking the nfal rig protocol (docs/protocol.md): "
        "its firmware (session, 2 kHz measurement stream, heartbeat, drive limit, watchdog that ramps the drive down "
        "when commands stop) and its hardware, the rig structure's blocks (the simulation's own FMU code, run "
        "in-process): resonance tracker (transducer + PLL), the levitated object (the 'truth' plant, with more damping "
        "at large gaps than the design model, as the paper reports) and the height sensor with its noise. The first "
        "line of output is the port to give the HardwareProxy (proxy.port); then one line per event. Runs until Ctrl-C "
        "or --duration.",
        epilog="Examples: nfal rig-emulator; then in another terminal: nfal run fig7_hil --param proxy.port=PATH "
        "--realtime. Faults: nfal rig-emulator --corrupt 0.01 --drop 0.01; nfal rig-emulator --disconnect-at 2 "
        "--reconnect-after 1. Another truth: nfal rig-emulator --truth reynolds; --param Plant.mass=0.15.")
    emulator.add_argument("--port", default="pty", metavar="pty|URL",
                          help="'pty': a new pseudo-terminal, reached at a stable symlink printed first (default); "
                          "or a pyserial URL to open (a device wired to the host's, socket://host:port)")
    emulator.add_argument("--link", metavar="PATH", help="with --port pty: where to put the symlink (default: a new "
                          "name in the temporary folder)")
    emulator.add_argument("--truth", default="slow", metavar="slow|reynolds|FILE",
                          help="the rig's hardware: rig_slow (slow model with the large-gap damping correction, "
                          "default), rig_reynolds (the full Reynolds film by harmonic balance, piston form; its cost "
                          "per 0.5 ms tick: docs/benchmarks.md), or an SSP of your own with the same element names")
    emulator.add_argument("--param", action="append", default=[], metavar="ELEMENT.VAR=VALUE",
                          help="override a parameter of the truth (repeatable), e.g. Plant.mass=0.15, "
                          "SensorChain.noise_peak=0")
    emulator.add_argument("--drop", type=finite_float, default=0.0, metavar="RATE",
                          help="drop this share of outgoing frames")
    emulator.add_argument("--corrupt", type=finite_float, default=0.0, metavar="RATE",
                          help="flip one bit in this share of outgoing frames")
    emulator.add_argument("--duplicate", type=finite_float, default=0.0, metavar="RATE",
                          help="send this share of outgoing frames twice")
    emulator.add_argument("--delay", type=finite_float, default=0.0, metavar="SECONDS",
                          help="hold every outgoing frame this long")
    emulator.add_argument("--disconnect-at", type=finite_float, metavar="SECONDS",
                          help="drop the port this long (rig time) after the host's first DRIVE (its reads fail)")
    emulator.add_argument("--reconnect-after", default="1.0", metavar="SECONDS|never",
                          help="reconnect the port this long after --disconnect-at (default 1.0)")
    emulator.add_argument("--seed", type=int, default=0, metavar="N", help="seed of the fault injection (default 0)")
    emulator.add_argument("--sample-rate", type=positive_float, default=1.0 / RigTiming.sample_period_s, metavar="HZ",
                          help="the rig's tick and measurement rate (default %(default)g; a host's HardwareProxy and "
                          "Controller take the same sample_rate; the C firmware runs at the default only)")
    emulator.add_argument("--watchdog", type=finite_float, default=RigTiming.watchdog_timeout_s, metavar="SECONDS",
                          help="no DRIVE for this long trips the watchdog (default %(default)s)")
    emulator.add_argument("--ramp-down", type=finite_float, default=RigTiming.ramp_down_s, metavar="SECONDS",
                          help="the watchdog's ramp of the drive to 0 V (default %(default)s)")
    emulator.add_argument("--max-voltage", type=finite_float, default=RigTiming.max_drive_voltage, metavar="V",
                          help="drive commands above this are clamped (default %(default)s)")
    emulator.add_argument("--duration", type=positive_float, metavar="SECONDS", help="stop after this long (default: "
                          "run until Ctrl-C or SIGTERM)")
    emulator.add_argument("--build-dir", default="build", metavar="DIR", help="where the rig structures are built "
                          "(default build/)")
    emulator.add_argument("--record", metavar="FILE.csv", type=output_file(".csv"), help="write every measurement the "
                          "rig takes in a session (before fault injection), with the applied voltage and the true "
                          "height")
    emulator.add_argument("--rt-priority", type=int, metavar="1-99", help="run the rig under SCHED_FIFO at this "
                          "priority, so the host's busy loop beside it cannot delay its ticks (Linux; needs root, "
                          "CAP_SYS_NICE or an rtprio limit; e.g. 50)")
    emulator.add_argument("--firmware", default="python", choices=("python", "c", "qemu"),
                          help="the rig's firmware: the Python one (default); c, the C reference firmware (firmware/) "
                          "built for this machine, on its own pty; qemu, the same C built for a Cortex-M4F and run in "
                          "qemu-system-arm (mps2-an386), protocol on its UART0. The truth is the same; see "
                          "docs/firmware.md. With c or qemu the port is a pty and no faults are injected")
    emulator.add_argument("--lockstep", action="store_true", help="once a session's first DRIVE has come, each tick "
                          "waits for the host's next DRIVE (up to 5 s of wall time): the rig runs on the host's steps, "
                          "not the wall clock. With a HardwareProxy that waits for each answer (proxy.lockstep=true), "
                          "the loop is the same whatever the machine's load: for tests and debugging, not timing. "
                          "With c or qemu the host's bytes then pass through the emulator, which holds them until a "
                          "DRIVE (the firmware's tunnel mode)")
    emulator.add_argument("--json", action="store_true", help="print the exit summary as JSON")
    emulator.set_defaults(handler=run_emulator)


def _truth_path(truth: str, build_dir: str) -> Path:
    if truth in ("slow", "reynolds"):
        name = f"rig_{truth}"
        return build_all(build_dir, structures=(name,))[name]
    path = Path(truth)
    if not path.exists():
        raise InvalidParameterError("--truth", truth, "slow, reynolds, or an existing .ssp/.ssd/folder "
                                    f"(nothing is at {path.absolute()})")
    return path


def _say(text: str) -> None:
    print(text, flush=True)


def run_emulator(args: argparse.Namespace) -> int:
    if not 10.0 <= args.sample_rate <= 20_000.0:
        raise InvalidParameterError("--sample-rate", args.sample_rate, "from 10 to 20000 Hz")
    timing = RigTiming(sample_period_s=1.0 / args.sample_rate, watchdog_timeout_s=args.watchdog,
                       ramp_down_s=args.ramp_down, max_drive_voltage=args.max_voltage)
    faults = FaultSettings(drop=args.drop, corrupt=args.corrupt, duplicate=args.duplicate, delay_s=args.delay,
                           seed=args.seed)
    after = None if args.reconnect_after == "never" else _seconds(args.reconnect_after)
    disconnection = None if args.disconnect_at is None else Disconnection(args.disconnect_at, after)
    if args.link and args.port != "pty":
        raise InvalidParameterError("--link", args.link, "used with --port pty only")
    parameters = dict(parse_parameter(text) for text in args.param)
    if args.sample_rate != 1.0 / RigTiming.sample_period_s:  # the rig's sensor and PLL sample at the rig's rate
        parameters.setdefault("SensorChain.sample_rate", str(args.sample_rate))
        parameters.setdefault("ResonanceTracker.pll_rate", str(args.sample_rate))
    if args.firmware != "python":
        _require_plain_link(args, faults, disconnection)
    require_realtime_priority(args.rt_priority)  # refused now, before anything is built or opened
    settings = EmulatorSettings(_truth_path(args.truth, args.build_dir), parameters, timing, port=args.port,
                                link=args.link, firmware=args.firmware, lockstep=args.lockstep, faults=faults,
                                disconnection=disconnection, record=Path(args.record) if args.record else None,
                                duration_s=args.duration, rt_priority=args.rt_priority)
    _print_report(serve_rig(settings, args.truth, _say), args.json)
    return 0


def _require_plain_link(args: argparse.Namespace, faults, disconnection) -> None:
    """--firmware c|qemu: the firmware owns its serial line, so nothing can be injected into it or unplugged."""
    if args.port != "pty":
        raise InvalidParameterError("--port", args.port, "pty with --firmware c or qemu (the firmware opens its own)")
    if args.sample_rate != 1.0 / RigTiming.sample_period_s:
        raise InvalidParameterError("--sample-rate", args.sample_rate, f"{1.0 / RigTiming.sample_period_s:g} with "
                                    "--firmware c or qemu (the C firmware's tick is built in)")
    if faults.active or disconnection is not None:
        raise InvalidParameterError("--firmware", args.firmware, "python when faults are injected (--drop, --corrupt, "
                                    "--duplicate, --delay, --disconnect-at): the C firmware writes its own line")


def _seconds(text: str) -> float:
    try:
        seconds = float(text)
    except ValueError:
        seconds = float("nan")
    if not seconds > 0:
        raise InvalidParameterError("--reconnect-after", text, "a number of seconds > 0, or 'never'")
    return seconds


def _print_report(report, as_json: bool) -> None:
    if as_json:
        print_json(dataclasses.asdict(report))
        return
    pacing = report.pacing
    lockstep = f" ({report.lockstep_ticks} on the host's DRIVE)" if report.lockstep_ticks else ""
    print(f"rig emulator: {report.ticks} ticks{lockstep}, {report.frames_sent} frames sent, final drive "
          f"{report.final_voltage:.3g} V", flush=True)
    if pacing:
        print(f"pacing: {pacing['overruns']} overruns; tick-start jitter p50 {pacing['jitter_p50_s'] * 1e6:.0f} us, "
              f"p99 {pacing['jitter_p99_s'] * 1e6:.0f} us, max {pacing['jitter_max_s'] * 1e6:.0f} us; tick "
              f"{pacing['step_duration_mean_s'] * 1e6:.0f} us mean; {pacing.get('resyncs', 0)} stalls "
              f"({pacing.get('time_given_up_s', 0.0) * 1e3:.1f} ms given up)", flush=True)
        if (stolen := steal_text(pacing.get("steal"))) is not None:
            print(stolen, flush=True)
    faults = report.faults
    print(f"faults injected into the rig's frames: {faults.get('dropped', 0)} withheld, {faults.get('corrupted', 0)} "
          f"corrupted, {faults.get('duplicated', 0)} sent twice (the host counts what it drops and what never came); "
          f"frames from the host the rig dropped: {report.decoder.get('dropped', 0)}", flush=True)
