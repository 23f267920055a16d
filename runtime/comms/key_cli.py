"""`mrta key FILE [--passphrase P]`: a MAVLink 2 signing key for a fleet (64 hex characters, mode 0600, never
overwrites).

Every robot's config names the same key file (``comms.signing_key``), and so does a ground station that commands
the fleet (`mrta mission ... --key FILE`).  Without ``--passphrase`` the key is 32 fresh random bytes; with it, the
key MAVProxy derives from the passphrase (SHA-256 of it, :func:`runtime.comms.link.passphrase_key`), so MAVProxy
signs with the fleet's key after ``signing key P``.  A robot never takes a key over the network (SETUP_SIGNING is
refused), so the key file is how a fleet gets it.
"""
from __future__ import annotations

import argparse

from runtime.comms.link import new_key, passphrase_key, write_key


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("key", help="make a fleet signing key file (MAVLink 2 signing)",
                       description="Write a 32-byte signing key as 64 hex characters, mode 0600: fresh random bytes, "
                                   "or with --passphrase the key a ground station derives from P (MAVProxy: "
                                   "`signing key P`).")
    p.add_argument("file", metavar="FILE", help="where to write it (refused if a file is there)")
    p.add_argument("--passphrase", metavar="P", default=None,
                   help="the key is SHA-256 of P, as MAVProxy's `signing key P` makes it (printable ASCII, no "
                        "spaces, quotes or ';')")
    p.set_defaults(func=_main)


def _main(args) -> int:
    if args.passphrase is None:
        path = new_key(args.file)
        print(f"{path}: new fleet signing key (give every robot's comms.signing_key and the ground station this file)")
    else:
        path = write_key(args.file, passphrase_key(args.passphrase, "--passphrase"))
        print(f"{path}: the fleet signing key of the passphrase (give every robot's comms.signing_key this file; "
              f"MAVProxy: signing key P)")
    return 0
