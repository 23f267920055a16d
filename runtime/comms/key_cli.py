"""`mrta key FILE`: a fresh MAVLink 2 signing key for a fleet (64 hex characters, mode 0600, never overwrites).

Every robot's config names the same key file (``comms.signing_key``), and so does a ground station that commands
the fleet (`mrta mission ... --key FILE`; MAVProxy: `signing setup` with the same bytes).
"""
from __future__ import annotations

import argparse

from runtime.comms.link import new_key


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("key", help="make a fleet signing key file (MAVLink 2 signing)",
                       description="Write a fresh 32-byte signing key as 64 hex characters, mode 0600.")
    p.add_argument("file", metavar="FILE", help="where to write it (refused if a file is there)")
    p.set_defaults(func=_main)


def _main(args) -> int:
    path = new_key(args.file)
    print(f"{path}: new fleet signing key (give every robot's comms.signing_key and the ground station this file)")
    return 0
