"""The ``nfal`` command line: parse, call, print. Each command group lives in ``nfal.cli.commands``, imported only when
one of its commands is dispatched (``nfal --help`` imports none)."""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
import traceback

from nfal import __version__
from nfal.cli.commands import COMMANDS
from nfal.errors import NfalError

#: The loggers of the FMU build, whose INFO lines (a build that is not a copy from the cache, the runtime's compilation)
#: every command shows: a first build takes tens of seconds.
BUILD_LOGGERS = ("nfal.fmus.build", "nfal.fmus.export_runtime")


def build_parser(dispatched: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser. The commands in ``dispatched`` (default: all) come with their options, their modules imported; the
    others with their line of ``nfal --help`` only."""
    parser = argparse.ArgumentParser(
        prog="nfal",
        description="Near-field acoustic levitation: squeeze-film physics (Reynolds and the simplified "
        "slow model), K(sigma) calibration, gain-scheduled control, and the closed loop of Fig. 7 as FMUs "
        "wired by SSP, and the same loop against the rig (hardware in the loop). Every quantity is SI.",
        epilog="Run 'nfal COMMAND --help' for a command's options.",
    )
    parser.add_argument("--version", action="version", version=f"nfal {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details to stderr")
    parser.add_argument("--debug", action="store_true", help="show the Python traceback of an error (for a bug report)")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    wanted = {COMMANDS[name].module for name in (COMMANDS if dispatched is None else dispatched) if name in COMMANDS}
    for module in dict.fromkeys(command.module for command in COMMANDS.values()):
        if module in wanted:
            importlib.import_module(f"nfal.cli.commands.{module}").register(commands)
        else:
            for name, command in COMMANDS.items():
                if command.module == module:
                    commands.add_parser(name, help=command.summary)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    command = next((arg for arg in argv if not arg.startswith("-")), None)  # the top level's options take no value
    args = build_parser([command] if command else []).parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    fmu_logger = logging.getLogger("nfal.fmus.base")
    level = fmu_logger.level
    if not args.verbose:  # an FMU's failure reaches the user once: in the error the command prints
        fmu_logger.setLevel(logging.CRITICAL)
    builds = [logging.getLogger(name) for name in BUILD_LOGGERS]
    build_levels = [builder.level for builder in builds]
    for builder in builds:  # a first build takes tens of seconds: it says so (a copy from the cache does not)
        builder.setLevel(logging.INFO)
    try:
        return int(args.handler(args) or 0)
    except NfalError as exc:
        return _fail(args, f"error: {exc}", 2)
    except OSError as exc:  # a path that cannot be read or written, a full disk: the user's to fix
        return _fail(args, f"error: {_os_error_text(exc)}", 2)
    except KeyboardInterrupt as exc:  # Ctrl-C, or a run's Interrupted (SIGTERM, SIGHUP): exit 128 + the signal
        return _fail(args, str(exc) or "interrupted", 128 + getattr(exc, "signal_number", 2))
    except Exception as exc:  # noqa: BLE001 - a bug: one line, the traceback only with --debug
        return _fail(args, f"internal error: {type(exc).__name__}: {exc} (rerun with --debug for the traceback, "
                     "and please report it)", 1)
    finally:
        fmu_logger.setLevel(level)
        for builder, build_level in zip(builds, build_levels):
            builder.setLevel(build_level)


def _fail(args: argparse.Namespace, message: str, code: int) -> int:
    if args.debug:
        traceback.print_exc()
    print(f"nfal {args.command}: {message}", file=sys.stderr)
    return code


def _os_error_text(exc: OSError) -> str:
    """``/x/y: Permission denied`` rather than ``[Errno 13] Permission denied: '/x/y'``."""
    if exc.strerror and exc.filename:
        return f"{exc.filename}: {exc.strerror}"
    return exc.strerror or str(exc)


if __name__ == "__main__":
    sys.exit(main())
