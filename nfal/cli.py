"""The ``nfal`` command line: parse, call, print. Each command group lives in ``nfal.commands``."""

from __future__ import annotations

import argparse
import logging
import sys

from nfal import __version__
from nfal.commands import control, cosim, hil, identify, physics, sweep
from nfal.models.errors import NfalError

COMMAND_GROUPS = (cosim, hil, identify, physics, control, sweep)


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
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for group in COMMAND_GROUPS:
        group.register(commands)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    fmu_logger = logging.getLogger("nfal.fmus.base")
    level = fmu_logger.level
    if not args.verbose:  # an FMU's failure reaches the user once: in the error the command prints
        fmu_logger.setLevel(logging.CRITICAL)
    try:
        return int(args.handler(args) or 0)
    except NfalError as exc:
        print(f"nfal {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"nfal {args.command}: interrupted", file=sys.stderr)
        return 130
    finally:
        fmu_logger.setLevel(level)


if __name__ == "__main__":
    sys.exit(main())
