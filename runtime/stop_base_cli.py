"""``mrta stop-base ROBOT.yaml``: write the base's stop on its port once, then exit; what a systemd unit runs as
``ExecStopPost`` after the daemon, however it ended (``docs/deploy.md``).

A Create (whose Open Interface has no watchdog) gets Drive Direct 0 0 and Start, which leaves it in Passive; a
Pioneer gets VEL 0, RVEL 0, STOP and CLOSE (its own watchdog stops it within 2 s anyway).  A CAN base is stopped
by its drives' heartbeat consumer 3 heartbeat periods after the daemon's last heartbeat: nothing is sent.  Exit 0
when the stop was written or there is nothing to write, 1 when the port took no bytes, 2 for a bad config or a port
that cannot open.
"""
from __future__ import annotations

import argparse

from runtime import config as C


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("stop-base", help="write the base's stop on its port (a systemd ExecStopPost), then exit",
                       description="Open the robot's base port, write the base's stop (the one the daemon's stop "
                                   "guard writes when the daemon dies), close it.  For after the daemon has exited.")
    p.add_argument("config", help="robot config YAML (the daemon's)")
    p.set_defaults(func=_main)


def _main(args) -> int:
    from runtime.drivers.registry import open_base

    cfg = C.load_robot(args.config)
    base = open_base(cfg.base, cfg.robot.id)
    stop = base.stop_bytes()
    if stop is None:
        print(f"{args.config}: base {cfg.base.type} stops by its own watchdog when its daemon stops: nothing sent")
        return 0
    link = base.link                      # a base with stop bytes is a serial one (MobileBase.stop_bytes)
    link.open()
    try:
        ok = link.write(stop[1])
    finally:
        link.close()
    if not ok:
        print(f"mrta: stop-base: {args.config}: base.port {link.url}: the stop could not be written", flush=True)
        return 1
    print(f"{args.config}: sent the {cfg.base.type} base's stop on {link.url}")
    return 0
