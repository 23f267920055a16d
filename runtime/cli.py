"""`mrta` command line: parse, load config, call.  Thin on purpose.

Each subcommand lives next to what it runs and exposes ``register(subparsers)``, which adds its
parser and sets ``func`` (taking the parsed args, returning an exit code).  Bad input anywhere
raises :class:`runtime.errors.InputError`; here it becomes one line on stderr and exit code 2.

Only the module of the command on the command line is imported (``mrta daemon`` on a robot never loads the
simulator's); ``mrta --help`` and :func:`build_parser` without arguments load them all.  The ``sitl`` and
``experiment`` commands need the ``[sitl]`` extra (pybullet, matplotlib): without it they say so in one line,
exit 2.
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys

from runtime.errors import InputError
from runtime import log

# command -> module that provides register(subparsers) for it, in help order
COMMANDS = {
    "daemon": "runtime.daemon_cli",                          # mrta daemon ROBOT_CONFIG
    "stop-base": "runtime.stop_base_cli",                    # mrta stop-base ROBOT_CONFIG (systemd ExecStopPost)
    "sitl": "sitl.launcher",                                 # mrta sitl run FLEET_CONFIG
    "assign": "runtime.allocation.formation.assign_cli",     # mrta assign PROBLEM.json
    "wdp": "runtime.allocation.coalition.wdp_cli",           # mrta wdp BIDS.json
    "experiment": "sitl.experiments.cli",                    # mrta experiment NAME
    "mission": "runtime.comms.mission_cli",                  # mrta mission upload|download|status TARGET ...
    "key": "runtime.comms.key_cli",                          # mrta key FILE
    "init-robot": "runtime.deploy.init_robot",               # mrta init-robot DIR --base create2|pioneer|can
    "schema": "runtime.config.schema_cli",                   # mrta schema robot|fleet|world
    "log": "runtime.recording.summary",                      # mrta log summary FILE.mcap
    "router": "runtime.comms.router_cli",                    # mrta router --listen tcp/HOST:PORT [--connect ...]
}
SIMULATOR = ("pybullet", "matplotlib")       # the [sitl] extra
NEEDS_SIMULATOR = "the simulator is not installed: pip install 'mrta-runtime[sitl]'"


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


def version() -> str:
    """The installed distribution's version (package metadata); "unknown" when run from a bare source tree."""
    from importlib.metadata import PackageNotFoundError, version as _version

    try:
        return _version("mrta-runtime")
    except PackageNotFoundError:
        return "unknown"


def _command(argv: list[str] | None) -> str | None:
    """The command word on ``argv`` (the first argument not an option), None when there is none."""
    return next((a for a in argv or () if not a.startswith("-")), None)


def simulator_missing() -> str | None:
    """The first of the [sitl] extra's packages that is not installed, else None."""
    import importlib.util

    for name in SIMULATOR:
        try:
            if importlib.util.find_spec(name) is None:
                return name
        except ImportError:
            return name
    return None


def _needs_simulator(func):
    """``func`` run only when the [sitl] extra is installed, else one line and exit 2."""
    def run(args):
        if simulator_missing():
            raise InputError(f"{args.command}: {NEEDS_SIMULATOR}")
        return func(args)
    return run


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The ``mrta`` parser.  With ``argv`` naming a command, only that command's module is imported."""
    parser = _Parser(prog="mrta", description="Multi-robot task allocation fleet runtime")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-vv for debug)")
    parser.add_argument("--version", action="version", version=f"mrta {version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    only = _command(argv) if _command(argv) in COMMANDS else None
    for command, name in COMMANDS.items():
        if only and command != only:
            continue
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:     # command not built in this checkout
                continue
            raise                    # a sitl module imports pybullet or matplotlib only when its command runs
        module.register(sub)
        if name.startswith("sitl.") and command in sub.choices:
            _wrap_funcs(sub.choices[command])
    return parser


def _wrap_funcs(parser: argparse.ArgumentParser) -> None:
    """Every ``func`` default of ``parser`` and its subparsers made to check for the simulator first."""
    if parser.get_default("func"):
        parser.set_defaults(func=_needs_simulator(parser.get_default("func")))
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                _wrap_funcs(child)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv)
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
    except BrokenPipeError:          # `mrta log summary F | head`: the reader left; say nothing more (Python's
        _quiet_stdout()              # own advice: point stdout at devnull so the exit flush does not raise again)
        return 141                   # 128 + SIGPIPE, what a shell reports for a command cut off by a pipe


def _quiet_stdout() -> None:
    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except (OSError, ValueError):    # stdout already closed, or not a real file (a test's capture)
        pass


if __name__ == "__main__":
    sys.exit(main())
