"""The ``nfal`` command line's commands: one module per group, each with ``register(subparsers)`` and the functions
that run its commands. :data:`COMMANDS` names them all, so that ``nfal --help`` lists every command without importing
any, and ``nfal COMMAND`` imports only its own module (``nfal.cli.build_parser``): a module imports what its commands
need at its top."""

from __future__ import annotations

from typing import NamedTuple


class Command(NamedTuple):
    module: str   #: the module of this package that defines and runs it
    summary: str  #: its line in ``nfal --help``


#: Every command, in ``nfal --help``'s order (a group's commands together).
COMMANDS: dict[str, Command] = {
    "build": Command("cosim", "build the FMUs and pack the SSP archives of the Fig. 7 loop"),
    "run": Command("cosim", "run a system structure: by default the closed loop of Fig. 7 (gain-scheduled PID, slow "
                   "plant)"),
    "rig-emulator": Command("hil", "play the levitation rig in real time on a pty (or a port) for hardware-in-the-loop "
                            "runs"),
    "identify": Command("identify", "identify the rig over its port: K(sigma) and the damping (Sec. 3.2.2, 3.3)"),
    "calibrate": Command("physics", "find the calibration function K(sigma) (Sec. 3.2)"),
    "validate": Command("physics", "reproduce the paper's validation results"),
    "design": Command("control", "gain-scheduled PID over the work range and its stability map (Sec. 4.1, Fig. 8)"),
    "compare": Command("control", "gain-scheduled vs. linear controllers on a staircase reference (Figs. 9-10)"),
    "sweep": Command("sweep", "run a sweep spec (grid or seeded random draws) on a local or remote Dask cluster"),
    "reproduce": Command("reproduce", "the paper's tables and figures, each number beside the paper's (an HTML "
                         "report)"),
}
