"""Every command's --help as a user reads it."""

import argparse
import subprocess
import sys

import pytest

from nfal.cli import build_parser


def _commands(parser: argparse.ArgumentParser, path=()):
    """(path, parser) for ``parser`` and every subcommand under it."""
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _commands(sub, (*path, name))


@pytest.mark.parametrize("parser", [pytest.param(parser, id=" ".join(path) or "nfal")
                                    for path, parser in _commands(build_parser())])
def test_help_shows_no_escaped_percent(parser):
    # argparse %-formats help= strings but prints a description as written: '%%' there reaches the user
    assert "%%" not in parser.format_help()


PROBE = """
import contextlib, io, sys
from nfal.cli import main
with contextlib.redirect_stdout(io.StringIO()) as out, contextlib.suppress(SystemExit):
    main(sys.argv[1:])
print(sorted(m for m in sys.modules if m.startswith("nfal.cli.commands.")))
print("rig-emulator" in out.getvalue() and "reproduce" in out.getvalue())
"""


@pytest.mark.slow  # a Python process per case
@pytest.mark.parametrize("argv, imported", [
    (["--help"], []),  # lists every command, imports none
    (["run", "--help"], ["nfal.cli.commands.common", "nfal.cli.commands.cosim"]),
    (["-v", "identify", "--help"], ["nfal.cli.commands.common", "nfal.cli.commands.identify"]),
])
def test_a_command_module_is_imported_when_dispatched(argv, imported):
    done = subprocess.run([sys.executable, "-c", PROBE, *argv], capture_output=True, text=True, check=True)
    modules, listed = done.stdout.splitlines()[-2:]
    assert modules == repr(imported)
    assert listed == str(argv == ["--help"])
