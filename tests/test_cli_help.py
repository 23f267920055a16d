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


def test_a_reader_that_leaves_the_pipe_gets_no_traceback():
    """`mrta schema robot | head -1`: the reader closes the pipe; mrta ends with 141 (as a shell shows a command cut
    off by SIGPIPE) and writes nothing to stderr, where Python's default is a BrokenPipeError traceback."""
    import os
    import subprocess
    import sys
    from pathlib import Path
    r, w = os.pipe()
    os.close(r)                                        # the reader is gone before the first write
    try:
        p = subprocess.run([sys.executable, "-m", "runtime.cli", "schema", "robot"], stdout=w, stderr=subprocess.PIPE,
                           text=True, timeout=60, cwd=Path(__file__).resolve().parents[1])
    finally:
        os.close(w)
    assert (p.returncode, p.stderr) == (141, "")
