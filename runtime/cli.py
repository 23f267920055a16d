"""`mrta` command line: parse, load config, call.  Thin on purpose.

Each subcommand lives next to what it runs and exposes ``register(subparsers)``, which adds its
parser and sets ``func`` (taking the parsed args, returning an exit code).  Bad input anywhere
raises :class:`runtime.errors.InputError`; here it becomes one line on stderr and exit code 2.
"""
from __future__ import annotations

import argparse
import importlib
import sys

from runtime.errors import InputError
from runtime import log

# module that provides register(subparsers), in help order
COMMANDS = (
    "runtime.daemon_cli",                # mrta daemon ROBOT_CONFIG
    "sitl.launcher",                     # mrta sitl run FLEET_CONFIG
    "runtime.allocation.formation.assign_cli",     # mrta assign PROBLEM.json
    "runtime.allocation.coalition.wdp_cli",        # mrta wdp BIDS.json
    "sitl.experiments.cli",              # mrta experiment NAME
    "runtime.comms.mission_cli",         # mrta mission upload|download|status TARGET ...
    "runtime.comms.key_cli",             # mrta key FILE
)


def _one_line(text: str) -> str:
    """``text`` with line breaks and other unprintable characters escaped (a file name may hold a newline)."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


class _Parser(argparse.ArgumentParser):
    """argparse with the project's error format: one line ``mrta: COMMAND: what is wrong`` on stderr, exit 2
    (subcommands' parsers are of the same class)."""

    def error(self, message: str):
        command = self.prog.removeprefix("mrta").strip()
        where = f"{command}: " if command else ""
        self.exit(2, f"mrta: {where}{_one_line(message)} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="mrta", description="Multi-robot task allocation fleet runtime")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-vv for debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:     # command not built in this checkout
                continue
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    log.setup({0: "WARNING", 1: "INFO"}.get(args.verbose, "DEBUG"))
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except InputError as exc:
        print(f"mrta: {_one_line(str(exc))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
