"""Every command and subcommand prints its --help (argparse formats help strings with %, so a stray
"%" in one crashes --help for the whole command)."""
from __future__ import annotations

import argparse

import pytest

from runtime import cli


def _parsers(parser: argparse.ArgumentParser, path=()):
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, path + (name,))


PARSERS = list(_parsers(cli.build_parser()))


def test_every_experiment_and_command_is_covered():
    names = {" ".join(p) for p, _ in PARSERS}
    assert {"daemon", "sitl run", "assign", "wdp", "experiment formation-world"} <= names


@pytest.mark.parametrize("path", [p for p, _ in PARSERS], ids=lambda p: " ".join(p) or "mrta")
def test_help_prints(path, capsys):
    with pytest.raises(SystemExit) as exit_:
        cli.main([*path, "--help"])
    assert exit_.value.code == 0
    assert "usage:" in capsys.readouterr().out
