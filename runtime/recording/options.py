"""The recording options the commands share: ``--record FILE.mcap`` and its bound (``mrta daemon``), and ``--live
[HOST:PORT]`` (``mrta daemon``, ``mrta sitl run``)."""
from __future__ import annotations

import argparse

from runtime.errors import InputError

LIVE_DEFAULT = "127.0.0.1:8765"      # Foxglove's own default WebSocket address


def add_live(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--live", nargs="?", const=LIVE_DEFAULT, default=None, metavar="HOST:PORT",
                   help=f"serve {what} over the Foxglove WebSocket protocol while it runs (default address "
                        f"{LIVE_DEFAULT}; open it in Foxglove: Open connection, Foxglove WebSocket)")


def add_record(p: argparse.ArgumentParser) -> None:
    p.add_argument("--record", default=None, metavar="FILE.mcap",
                   help="record the robot (poses, path, commands, ranges, allocation events, logs) into this MCAP "
                        "file, on the system clock (on the simulator's in SITL); see docs/recording.md")
    p.add_argument("--record-limit", type=float, default=1024.0, metavar="MB",
                   help="with --record: the file's size limit in MB (default 1024); at the limit the recording "
                        "stops, or with --record-rotate goes on in FILE.1.mcap, FILE.2.mcap, ...")
    p.add_argument("--record-rotate", action="store_true", help="with --record: rotate files at --record-limit")
    p.add_argument("--record-mavlink", action="store_true",
                   help="with --record: the raw MAVLink frames of the robot's link too (a replayable record)")


def live_address(text: str | None) -> tuple[str, int] | None:
    """``--live``'s HOST:PORT, or an InputError naming the option."""
    if text is None:
        return None
    host, sep, port = text.rpartition(":")
    if not sep or not host or not (port.isascii() and port.isdigit()) or not 0 < int(port) < 65536:
        raise InputError(f"--live: expected HOST:PORT with a port in 1..65535, got {text!r}")
    return host, int(port)


def check_record(args) -> None:
    """``--record``'s file can be written and ``--record-limit`` is a size."""
    from runtime import argcheck

    argcheck.output_file(args.record, "--record")
    argcheck.number(args.record_limit, "--record-limit", 0.0, lo_open=True)
    live_address(args.live)
