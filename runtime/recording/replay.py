"""``mrta log replay FILE.mcap --to HOST:PORT [--speed X]``: a recording's raw MAVLink frames sent again, at their
recorded pace, to a UDP address, so a ground station (QGroundControl, MAVProxy, ``mrta gcs``) watches a past run as
if the robots were there.

The frames are the ``/robot_N/mavlink`` channels (``mrta.MavlinkFrames``, a robot's frames of one control cycle
in one message, each with its own time; on in SITL, ``--record-mavlink`` on a robot; files written before the
batching have one ``mrta.MavlinkFrame`` a message, read too): by default what the robots sent (``tx``), every robot
in the file; ``--robot N`` picks robots, ``--rx`` adds what they received.  Each datagram goes out as it was
recorded (signed frames stay signed), at its time from the first frame divided by ``--speed``, in time order.  A
frame that does not parse (its hex, its fields) is skipped and counted.
"""
from __future__ import annotations

import socket
import sys
import time

from runtime.errors import InputError


def add_parser(sub) -> None:
    r = sub.add_parser("replay", help="send a recording's raw MAVLink frames to a UDP address at their recorded "
                                      "pace (a ground station watches a past run)")
    r.add_argument("file", help="an MCAP recording with raw MAVLink frames (RUN_DIR/run.mcap, RUN_DIR/robot_N.mcap, "
                                "mrta daemon --record FILE.mcap --record-mavlink)")
    r.add_argument("--to", required=True, metavar="HOST:PORT", help="the UDP address to send the frames to "
                                                                   "(a ground station's, e.g. 127.0.0.1:14550)")
    r.add_argument("--speed", type=float, default=1.0, metavar="X",
                   help="play X times as fast as recorded (default 1)")
    r.add_argument("--robot", type=int, action="append", default=None, metavar="N",
                   help="only robot N's frames (repeat for more; default every robot in the file)")
    r.add_argument("--rx", action="store_true", help="also the frames the robots received (default: only sent)")
    r.set_defaults(func=_main)


def frames(path, robots=None, rx: bool = False) -> tuple[list[tuple[int, int, bytes]], int]:
    """The recording's raw MAVLink frames to replay as (time ns, robot, datagram), in time order (file order
    among equal times), and how many were skipped (a frame that does not parse)."""
    from runtime.recording.read import read_messages

    rec = read_messages(path)
    out, skipped = [], 0
    for m in rec.messages:
        if m.kind != "mavlink" or m.robot is None or (robots and m.robot not in robots):
            continue
        batch = m.data.get("frames") if isinstance(m.data, dict) else None
        for d in ([m.data] if batch is None else batch if isinstance(batch, list) else [None]):
            try:
                if d.get("direction") != "tx" and not rx:
                    continue
                out.append((int(d.get("ns", m.ns)), m.robot, bytes.fromhex(d["frame"])))
            except (AttributeError, KeyError, TypeError, ValueError):
                skipped += 1
    out.sort(key=lambda item: item[0])
    if not out:
        which = "" if not robots else f" of robot {', '.join(map(str, robots))}"
        raise InputError(f"{path}: expected raw MAVLink frames{which} (/robot_N/mavlink: SITL runs record them, "
                         f"a robot with --record-mavlink), found none")
    return out, skipped


def replay(items, address: tuple[str, int], speed: float = 1.0, stop=None) -> int:
    """Send ``items`` ((ns, robot, datagram), ...) to ``address`` at their pace over ``speed``; the number sent.
    ``stop()``: end early when it says so."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sent = 0
    try:
        t0 = items[0][0]
        start = time.monotonic()
        for ns, _, data in items:
            due = start + (ns - t0) / 1e9 / speed
            while True:
                if stop is not None and stop():
                    return sent
                wait = due - time.monotonic()
                if wait <= 0:
                    break
                time.sleep(min(wait, 0.1))
            try:
                sock.sendto(data, address)
                sent += 1
            except OSError as exc:       # nobody listening (ICMP refused) is no reason to stop a replay
                if not isinstance(exc, ConnectionRefusedError):
                    raise
    finally:
        sock.close()
    return sent


def _main(args) -> int:
    from runtime import argcheck
    from runtime.recording.options import live_address

    address = live_address(args.to, "--to")
    argcheck.number(args.speed, "--speed", 0.0, lo_open=True)
    items, skipped = frames(args.file, set(args.robot) if args.robot else None, args.rx)
    robots = sorted({r for _, r, _ in items})
    span = (items[-1][0] - items[0][0]) / 1e9
    print(f"replaying {len(items)} frames of robot(s) {', '.join(map(str, robots))} ({span:.1f} s recorded) to "
          f"{address[0]}:{address[1]} at {args.speed:g}x", file=sys.stderr)
    try:
        sent = replay(items, address, args.speed)
    except KeyboardInterrupt:
        print("replay stopped", file=sys.stderr)
        return 130
    print(f"sent {sent} frames" + (f" ({skipped} skipped: not a frame)" if skipped else ""))
    return 0
