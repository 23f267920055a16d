"""``mrta daemon ROBOT.yaml``: check the robot config, build the daemon (:mod:`runtime.daemon`) and run it on the
wall clock, or on the simulator's clock in SITL."""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from runtime import config as C
from runtime import daemon as D
from runtime.clock import Clock, ScaledClock, SharedClock, WallClock


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("daemon", help="run one robot's daemon from its robot config")
    p.add_argument("config", help="robot config YAML")
    p.add_argument("--check", action="store_true",
                   help="run every check start-up runs (addresses, peers, map, signing key, base options) without "
                        "opening a device or a socket, then exit: 0 ok, 2 with one line saying what is wrong")
    p.add_argument("--speedup", type=float, default=None,
                   help="SITL only: run on a scaled clock this many times faster than real time")
    p.add_argument("--epoch", type=float, default=None,
                   help="SITL only: monotonic-clock epoch shared with the simulator")
    p.add_argument("--clock-file", default=None,
                   help="SITL only: when built, write FILE.ready.ID, wait for FILE, then take the "
                        "simulator's time from it")
    p.add_argument("--listen-fd", type=int, default=None, metavar="FD",
                   help="take comms.listen's UDP socket already bound, as inherited file descriptor FD (the SITL "
                        "launcher holds each robot's port from its check on and hands it over so)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many (clock) seconds")
    p.add_argument("--stats", default=None, help="write a JSON status snapshot here every second")
    from runtime.recording.options import add_live, add_live_relay, add_record
    add_record(p)
    add_live(p, "this robot's recording channels")
    add_live_relay(p)
    p.set_defaults(func=_main)


def _wait_for_clock(path: str, robot_id: int, timeout: float = 120.0) -> None:
    """SITL start barrier: say we are built, then wait for the simulator to publish its clock."""
    try:
        Path(f"{path}.ready.{robot_id}").touch()
    except OSError as exc:
        raise C.ConfigError(path, "clock", f"a folder to write {Path(path).name}.ready.{robot_id} in "
                            f"({exc.strerror})") from None
    deadline = time.monotonic() + timeout
    while not Path(path).exists():
        if time.monotonic() > deadline:
            raise C.ConfigError(path, "clock", f"the simulator to start within {timeout:.0f} s")
        time.sleep(0.01)


def _inherited(fd: int | None):
    """The socket of inherited descriptor ``fd`` (None: none), or an InputError naming --listen-fd."""
    if fd is None:
        return None
    import socket

    from runtime.errors import InputError
    try:
        return socket.socket(fileno=fd)
    except OSError as e:
        raise InputError(f"--listen-fd: expected an open UDP socket's descriptor, got {fd} ({e.strerror})") from None


def _check_args(args) -> None:
    """The options, before anything starts: numbers in range, output files in folders that exist."""
    from runtime import argcheck

    argcheck.number(args.speedup, "--speedup", 0.0, lo_open=True)
    argcheck.number(args.epoch, "--epoch")
    argcheck.number(args.duration, "--duration", 0.0, lo_open=True)
    argcheck.number(args.listen_fd, "--listen-fd", 3, 65535)
    argcheck.output_file(args.stats, "--stats")
    argcheck.output_file(args.clock_file, "--clock-file")
    from runtime.recording.options import check_record
    check_record(args)


def _main(args) -> int:
    _check_args(args)
    cfg = C.load_robot(args.config)
    C.validate_robot(cfg)             # what start-up needs, checked before any device or socket opens
    if args.check:
        from runtime.comms import codec, dialect
        codec.check(dialect.load())   # the MAVLink bindings: shipped, or generated into a cache it can write
        print(f"{args.config}: ok (robot {cfg.robot.id}, base {cfg.base.type}, allocation {cfg.allocation.method})")
        return 0
    daemon = D.Daemon(cfg, listen_socket=_inherited(args.listen_fd))
    if args.clock_file:
        _wait_for_clock(args.clock_file, cfg.robot.id)
        clock: Clock = SharedClock(args.clock_file, args.speedup or 1.0)
    elif args.speedup is not None or args.epoch is not None:
        clock = ScaledClock(args.speedup or 1.0, args.epoch)
    else:
        clock = WallClock()
    if cfg.comms.signing_key is None:
        daemon.log.warning("MAVLink signing is off (comms.signing_key is not set): any host on the network can "
                           "command this robot")
    recording = _recording(args, daemon, wall=isinstance(clock, WallClock))
    try:
        return D.run(daemon, clock, args.duration, args.stats)
    finally:
        if recording is not None:
            recording.close()


def _recording(args, daemon: D.Daemon, wall: bool):
    """``--record`` / ``--live``: a recorder fed by the daemon's core (and its link's frames with
    ``--record-mavlink``), or None."""
    if args.record is None and args.live is None and args.live_relay is None:
        return None
    from runtime.errors import InputError
    from runtime.recording.feed import Recording
    from runtime.recording.options import live_address
    from runtime.recording.recorder import RecordingUnavailable

    try:
        return Recording.of_daemon(daemon, args.record, wall=wall, limit=int(args.record_limit * 1e6),
                                   rotate=args.record_rotate, live=live_address(args.live),
                                   mavlink=args.record_mavlink, relay=live_address(args.live_relay, "--live-relay"))
    except RecordingUnavailable as exc:
        raise InputError(f"--record: {exc}") from None
    except OSError as exc:
        raise InputError(f"--record {args.record}: expected a file that can be written ({exc.strerror or exc})") \
            from None
