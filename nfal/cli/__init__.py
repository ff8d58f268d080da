"""The ``nfal`` command line: parse, call, print. Each command group lives in ``nfal.cli.commands``."""

from __future__ import annotations

import argparse
import logging
import sys
import traceback

from nfal import __version__
from nfal.cli.commands import control, cosim, hil, identify, physics, reproduce, sweep
from nfal.errors import NfalError

COMMAND_GROUPS = (cosim, hil, identify, physics, control, sweep, reproduce)


def build_parser() -> argparse.ArgumentParser:
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
    for group in COMMAND_GROUPS:
        group.register(commands)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    fmu_logger = logging.getLogger("nfal.fmus.base")
    level = fmu_logger.level
    if not args.verbose:  # an FMU's failure reaches the user once: in the error the command prints
        fmu_logger.setLevel(logging.CRITICAL)
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
