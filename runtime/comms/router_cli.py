"""`mrta router --listen tcp/HOST:PORT [--connect tcp/OTHER:PORT ...]`: a Zenoh router for one radio segment (the
``zenoh`` transport's client robots connect to it; routers of several segments are linked with ``--connect``).

A Python Zenoh session in router mode (:func:`runtime.comms.zenoh_transport.open_router`; needs the ``[zenoh]``
extra).  A site may run Eclipse's ``zenohd`` instead: the same wire, and its config file adds TLS and access control
(docs/transport.md).  Runs until SIGTERM/SIGINT or ``--duration``.
"""
from __future__ import annotations

import argparse
import signal
import time


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("router", help="run a Zenoh router for one segment of a fleet (comms.transport: zenoh)",
                       description="A Zenoh router (a Python session in router mode): robots in client mode connect "
                                   "to it; --connect links it to other segments' routers.")
    p.add_argument("--listen", action="append", required=True, metavar="ENDPOINT",
                   help="where robots connect, e.g. tcp/0.0.0.0:7447 (repeatable)")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="another segment's router to link to, e.g. tcp/10.0.2.1:7447 (repeatable)")
    p.add_argument("--config", default=None, metavar="FILE",
                   help="a Zenoh JSON5 config file under --listen/--connect: TLS, access control (docs/transport.md)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    p.set_defaults(func=_main)


class _Stop(BaseException):
    pass


def _main(args) -> int:
    from runtime import argcheck
    from runtime.comms.zenoh_transport import open_router, parse_endpoint
    from runtime.errors import InputError

    argcheck.number(args.duration, "--duration", 0.0, lo_open=True)
    for opt, values in (("--listen", args.listen), ("--connect", args.connect)):
        for v in values:
            try:
                parse_endpoint(v)
            except ValueError as e:
                raise InputError(f"{opt}: expected a Zenoh endpoint PROTO/HOST:PORT ({e}), got {v!r}") from None

    def _stop(signum, frame):
        raise _Stop()

    before = {s: signal.signal(s, _stop) for s in (signal.SIGTERM, signal.SIGINT)}
    session = None
    try:
        session = open_router(args.listen, args.connect, file=args.config)
        print(f"router {session.info.zid()} listening on {', '.join(args.listen)}"
              + (f", linked to {', '.join(args.connect)}" if args.connect else ""), flush=True)
        end = None if args.duration is None else time.monotonic() + args.duration
        while end is None or time.monotonic() < end:
            time.sleep(0.2 if end is None else max(0.0, min(0.2, end - time.monotonic())))
    except _Stop:
        pass
    finally:
        for s, h in before.items():
            signal.signal(s, h)
        if session is not None:
            session.close()
    return 0
