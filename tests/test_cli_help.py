"""Every command's --help as a user reads it."""

import argparse

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
