"""The recording's channels and sinks: an MCAP file (bounded: rotate or stop) and a Foxglove WebSocket server.

One :class:`Recorder` per recording: a fleet in lock-step SITL records every robot into one file, a daemon
(``mrta daemon ROBOT.yaml --record FILE.mcap``) records its own robot.  The channels use Foxglove's well-known schemas
where one fits (``foxglove.PoseInFrame``, ``FrameTransform``, ``PosesInFrame``, ``PointCloud``, ``SceneUpdate``,
``Log``) and named JSON schemas for the rest (allocation events, wheel commands, bumpers); the topics are in
:data:`TOPICS`.  ``foxglove-sdk`` (the ``[record]`` extra) writes both, from Rust: one pose costs a few
microseconds.  Times are given in seconds of the host's clock and written as nanoseconds: the simulated clock in
SITL (``wall=False``), the system clock on a robot (``wall=True``, whatever the host's ``now``).

A write the disk refuses (full, gone) ends the recording with one warning line and never reaches the host; so does
reaching ``limit`` bytes without ``rotate`` (with it, the file is closed and the next one, ``NAME.1.mcap``,
``NAME.2.mcap``, ..., opened).
"""
from __future__ import annotations

import json
import math
import struct
import time
from pathlib import Path

from runtime.errors import InputError
from runtime.log import get_logger

WORLD = "world"                     # the fixed frame every pose is in
CHUNK = 256 * 1024                  # bytes of messages per MCAP chunk: what a killed recorder loses at most
SCAN_BINS = 360                     # a laser scan's equal angular steps (1 degree: an RPLIDAR A1's resolution)
FRAME_BATCH = 0.5                   # s of the recording's clock a robot's raw MAVLink frames are held, then one message
LIVE_BACKLOG = 16384                # messages the live server holds per client before it drops the oldest
TOPICS = {                          # topic (robot topics: {id} is the robot id) -> schema name
    "/robot_{id}/pose": "foxglove.PoseInFrame",        # the robot's own estimate, every control cycle
    "/robot_{id}/truth": "foxglove.PoseInFrame",       # SITL: where the body really is, every control cycle
    "/tf": "foxglove.FrameTransforms",                 # world -> robot_{id} of every robot, once a cycle
    "/robot_{id}/path": "foxglove.PosesInFrame",       # the path the robot follows, when it changes
    "/robot_{id}/command": "mrta.WheelCommand",        # (v, w) to the base, every control cycle
    "/robot_{id}/ranges": "foxglove.PointCloud",       # range readings (sonar, laser) in the robot's frame
    "/robot_{id}/scan": "foxglove.LaserScan",          # the robot's laser (sensors: rplidar), one revolution
    "/robot_{id}/bumpers": "mrta.Bumpers",             # bumpers and wheel drops, when they change
    "/world": "foxglove.SceneUpdate",                  # arena, obstacles and task places coloured by state
    "/allocation": "mrta.AllocationEvent",             # messages sent and received, commitments, progress, tasks
    "/log": "foxglove.Log",                            # every log record and the STATUSTEXT lines
    "/robot_{id}/mavlink": "mrta.MavlinkFrames",       # raw MAVLink frames of the robot's link (optional), up
    #                                                    to FRAME_BATCH s of them in one message
    "/robot_{id}/stats": "mrta.RobotStats",            # the daemon's status snapshot (counters), every second
}

_ANY = {"type": "object", "additionalProperties": True}
SCHEMAS = {
    "mrta.WheelCommand": {"type": "object", "title": "mrta.WheelCommand", "properties": {
        "robot": {"type": "integer"}, "v": {"type": "number", "description": "m/s"},
        "w": {"type": "number", "description": "rad/s"}}},
    "mrta.Bumpers": {"type": "object", "title": "mrta.Bumpers", "properties": {
        "robot": {"type": "integer"}, "left": {"type": "boolean"}, "right": {"type": "boolean"},
        "wheel_drop": {"type": "boolean"}, "faults": {"type": "array", "items": {"type": "string"}}}},
    "mrta.AllocationEvent": {"type": "object", "title": "mrta.AllocationEvent", "properties": {
        "robot": {"type": "integer", "description": "the robot whose event it is (0: the SITL operator)"},
        "event": {"type": "string", "description": "sent | received | committed | released | progress | task | "
                                                   "peer_lost | operator"},
        "t": {"type": "number", "description": "s, the host's clock (sim time in SITL)"},
        "task": {"type": ["integer", "null"]},
        "message": {"type": "string", "description": "the message's type (sent, received), the progress or task "
                                                     "state, the operator's event"},
        "robots": {"type": "array", "items": {"type": "integer"}},
        "fields": _ANY}},
    "mrta.RobotStats": {"type": "object", "title": "mrta.RobotStats", "description": "the daemon's status snapshot: "
                        "cycles, messages sent and received, drops by reason, the link's counters",
                        "additionalProperties": True},
    "mrta.MavlinkFrames": {"type": "object", "title": "mrta.MavlinkFrames", "description": "the raw MAVLink "
                           "datagrams of the robot's link since the last message (up to half a second's), in order",
                           "properties": {
        "robot": {"type": "integer"},
        "frames": {"type": "array", "items": {"type": "object", "properties": {
            "ns": {"type": "integer", "description": "when the link sent or took it: the recording's clock, ns"},
            "direction": {"type": "string", "description": "tx | rx"},
            "address": {"type": "string", "description": "HOST:PORT it went to or came from ('' if none)"},
            "frame": {"type": "string", "description": "the datagram, hex"}}}}}},
}
ENCODED = ("foxglove.PoseInFrame", "foxglove.FrameTransforms")    # written as protobuf bytes encoded here
TASK_COLOURS = {"open": (1.0, 0.6, 0.1), "held": (0.2, 0.45, 1.0), "done": (0.2, 0.75, 0.3),
                "withdrawn": (0.5, 0.5, 0.5), "cleared": (0.5, 0.5, 0.5)}


class RecordingUnavailable(RuntimeError):
    """The ``[record]`` extra is not installed."""


def _fx():
    try:
        import foxglove
        import foxglove.messages  # noqa: F401
    except ImportError:
        raise RecordingUnavailable("recording needs foxglove-sdk: pip install 'mrta-runtime[record]'") from None
    return foxglove


class _File:
    """The MCAP writer's file: counts the bytes written; a write the disk refuses is kept as ``error`` and not
    raised (the writer lives in Rust, inside the host's control cycle).  After an error the file's position goes
    on as if the writes had landed (the writer checks it), until :meth:`Recorder.check` closes the recording."""

    def __init__(self, path: Path):
        self.path = path
        self.fh = open(path, "wb")
        self.bytes = 0
        self.pos = 0
        self.error: OSError | None = None

    def write(self, data) -> int:
        if self.error is None:
            try:
                self.fh.write(data)
                self.bytes += len(data)
            except OSError as exc:
                self.error = exc
        self.pos += len(data)
        return len(data)

    def seek(self, offset: int, whence: int = 0) -> int:
        if self.error is None:
            try:
                self.pos = self.fh.seek(offset, whence)
                return self.pos
            except OSError as exc:
                self.error = exc
        self.pos = offset if whence == 0 else self.pos + offset if whence == 1 else self.pos
        return self.pos

    def tell(self) -> int:
        return self.pos

    def flush(self) -> None:
        if self.error is None:
            try:
                self.fh.flush()
            except OSError as exc:
                self.error = exc

    def close(self) -> None:
        try:
            self.fh.close()
        except OSError as exc:
            self.error = self.error or exc


class Recorder:
    """Channels on one Foxglove context, sunk into ``path`` (an MCAP file; None: none) and, with ``live``
    ``(host, port)``, a Foxglove WebSocket server.  ``limit``: bytes per file (None: unbounded); ``rotate``: at the
    limit go on in the next file, else stop.  ``mavlink``: record raw MAVLink frames (:meth:`frame`)."""

    def __init__(self, path: str | Path | None = None, *, wall: bool = False, limit: int | None = None,
                 rotate: bool = False, live: tuple[str, int] | None = None, mavlink: bool = False,
                 chunk_size: int = CHUNK, name: str = "mrta", robot_id: int | str | None = None,
                 flush_period: float | None = None, relay: tuple[str, int] | None = None):
        fx = _fx()
        self.fx = fx
        self.m = fx.messages
        self.log = get_logger("recording", robot_id)
        self.wall = wall
        self.limit = limit
        self.rotate = rotate
        self.mavlink = mavlink
        self.chunk_size = chunk_size
        self.flush_period = flush_period      # wall s between chunk flushes: a killed recorder loses at most this
        self._next_flush = time.monotonic() + (flush_period or 0.0)
        self.ctx = fx.Context()
        self.target = None if path is None else Path(path)
        self.files: list[Path] = []          # every file written, in order
        self.stopped: str | None = None      # why the file recording ended early
        self._file: _File | None = None
        self._writer = None
        self._last_ns = 0
        self._channels: dict[str, object] = {}
        self._by_robot: dict[tuple[int, str], object] = {}
        self._metadata: list[tuple[str, dict]] = []
        self._frame_heads: dict[tuple, str] = {}
        self._taps: dict[int, FrameTap] = {}  # robot id -> its link's tap, holding its raw frames not yet written
        self._frames_due: int | None = None   # when (ns) the held frames are written (check), None: none held
        self._now_seen = math.nan             # the last ``now`` stamped (the clock's ns of it is _last_ns)
        self._ts_ns, self._ts_last = -1, None
        self._pb_ts_ns, self._pb_ts = -1, b""
        self._parts_cache: dict[tuple, tuple] = {}
        self.server = None
        self.relay = None                    # a RelaySender: every message also to a SITL launcher (--live-relay)
        self._relay_ids: dict[int, int] = {}     # id(channel) -> the relay's channel id
        self._relayed: dict[str, object] = {}    # topic -> a channel the launcher relays from a daemon
        if relay is not None:
            from runtime.recording.relay import RelaySender
            try:
                self.relay = RelaySender(relay, int(robot_id or 0))
            except OSError as exc:
                self.log.warning("live relay to %s:%d not open: %s (the robot runs on)", relay[0], relay[1],
                                 exc.strerror or exc)
        if self.target is not None:
            self._open(self.target)
        if live is not None:
            host, port = live
            try:
                self.server = fx.start_server(name=name, host=host, port=port, context=self.ctx,
                                              message_backlog_size=LIVE_BACKLOG)
            except RuntimeError as exc:          # foxglove's FoxgloveError: the address is taken or unknown
                self.close()
                raise InputError(f"--live {host}:{port}: expected an address free to serve on ({exc})") from None
        self.stamp(0.0)

    # ------------------------------------------------------------------ sinks
    def _open(self, path: Path) -> None:
        from foxglove.mcap import MCAPWriteOptions

        self._file = _File(path)
        opts = MCAPWriteOptions(chunk_size=self.chunk_size, compression_threads=0, profile="")
        self._writer = self.fx.open_mcap(self._file, context=self.ctx, writer_options=opts,
                                         channel_filter=_not_relayed)
        self.files.append(path)
        for name, data in self._metadata:        # a rotated file carries the recording's metadata too
            self._writer.write_metadata(name, data)

    def _close_file(self) -> None:
        if self._writer is not None:
            try:
                self._writer.close()
            except Exception as exc:       # the writer's own I/O error: the file is what was written
                self.log.debug("closing %s: %s", self._file.path, exc)
            self._file.close()
            self._writer = None

    def check(self) -> None:
        """The file's bound and health, once a cycle: rotate or stop at the limit; a refused write ends the file
        recording with one warning line.  Raw MAVLink frames held FRAME_BATCH s go out, one message a robot;
        then a live relay sends what it holds."""
        if self._frames_due is not None and self._last_ns >= self._frames_due:
            self._write_frames()
        if self.relay is not None:
            self.relay.flush()
        f = self._file
        if f is None:
            return
        if f.error is not None:
            self._close_file()
            self._file = None
            self.stopped = f"{f.path}: {f.error.strerror or f.error}"
            self.log.warning("recording stopped: %s (the robot runs on)", self.stopped)
        elif self.flush_period is not None and time.monotonic() >= self._next_flush:
            self._next_flush = time.monotonic() + self.flush_period
            self._write_frames()
            self._writer.flush()
        if self._file is not None and self.limit is not None and self._file.bytes >= self.limit:
            self._close_file()
            self._file = None
            if self.rotate:
                stem = self.target.name[:-5] if self.target.name.endswith(".mcap") else self.target.name
                self._open(self.target.with_name(f"{stem}.{len(self.files)}.mcap"))
            else:
                self.stopped = f"{f.path}: the size limit ({self.limit} bytes) reached"
                self.log.warning("recording stopped: %s", self.stopped)

    def flush(self) -> None:
        if self._writer is not None:
            self._writer.flush()

    def fail(self, exc: BaseException) -> None:
        """The writer itself failed (an error, or a panic in the Rust library): end the file recording with one
        warning line."""
        if self._file is None:
            return
        path = self._file.path
        self._file.error = self._file.error or OSError(str(exc))
        try:
            self._close_file()
        except BaseException as again:       # the library's panic on the way out: the file is what it is
            if not recoverable(again):
                raise
        self._file = None
        self.stopped = f"{path}: {type(exc).__name__}: {exc}"
        self.log.warning("recording stopped: %s (the robot runs on)", self.stopped)

    def metadata(self, name: str, data: dict) -> None:
        """A metadata record (string values; others as JSON), in this file and every later one."""
        data = {k: v if isinstance(v, str) else json.dumps(v, separators=(",", ":")) for k, v in data.items()}
        self._metadata.append((name, data))
        if self._writer is not None:
            self._writer.write_metadata(name, data)

    def close(self) -> None:
        self._write_frames()
        self._close_file()
        self._file = None
        if self.relay is not None:
            self.relay.close()
        if self.server is not None:
            self.server.stop()
            self.server = None

    @property
    def port(self) -> int | None:
        return None if self.server is None else self.server.port

    # ------------------------------------------------------------------ time
    def stamp(self, now: float) -> int:
        """``now`` (s) as the recording's time in ns, never before the last one: the simulated clock, or the
        system clock on a robot."""
        if self.wall:
            ns = time.time_ns()
        elif now == self._now_seen or not math.isfinite(now):     # the same step's time again: its ns
            return self._last_ns
        else:
            self._now_seen = now
            ns = int(round(now * 1e9))
        if ns > self._last_ns:
            self._last_ns = ns
        return self._last_ns

    @property
    def ns(self) -> int:
        return self._last_ns

    def _ts(self, ns: int):
        """A foxglove Timestamp of ``ns``: one object for every message of a cycle (the messages copy it)."""
        if ns != self._ts_ns:
            self._ts_ns, self._ts_last = ns, self.m.Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)
        return self._ts_last

    # ------------------------------------------------------------------ channels
    def channel(self, topic: str, schema: str):
        ch = self._channels.get(topic)
        if ch is None:
            fx = self.fx
            if schema in ENCODED:             # the schema's own (protobuf) channel, logged bytes (:func:`_pose_pb`)
                ch = fx.Channel(topic, context=self.ctx, message_encoding="protobuf",
                                schema=getattr(self.m, schema.split(".", 1)[1]).get_schema())
            elif schema.startswith("foxglove."):
                cls = getattr(fx.channels, schema.split(".", 1)[1] + "Channel")
                ch = cls(topic, context=self.ctx)
            else:
                ch = fx.Channel(topic, context=self.ctx, message_encoding="json",
                                schema=fx.Schema(name=schema, encoding="jsonschema",
                                                 data=json.dumps(SCHEMAS[schema]).encode()))
            self._channels[topic] = ch
            if self.relay is not None:
                if schema.startswith("foxglove."):
                    sch, enc = getattr(self.m, schema.split(".", 1)[1]).get_schema(), "protobuf"
                else:
                    sch, enc = fx.Schema(name=schema, encoding="jsonschema",
                                         data=json.dumps(SCHEMAS[schema]).encode()), "json"
                self._relay_ids[id(ch)] = self.relay.channel(topic, enc, sch)
        return ch

    def _log(self, ch, msg, ns: int) -> None:
        """``msg`` (a foxglove message, or JSON text) on ``ch`` at ``ns``, and to the live relay if there is one.
        JSON text and encoded bytes go to the channel's base (what ``Channel.log`` does after its type checks)."""
        kind = type(msg)
        if kind is str:
            msg, kind = msg.encode(), bytes
        if kind is bytes:
            ch.base.log(msg, ns)
        else:
            ch.log(msg, log_time=ns)
            if self.relay is not None:
                msg = msg.encode()               # foxglove's: protobuf
        if self.relay is not None:
            self.relay.send(self._relay_ids[id(ch)], msg, ns)

    def relayed_channel(self, topic: str, encoding: str, schema, robot: int):
        """A channel for what a daemon relays (:class:`~runtime.recording.relay.RelayServer`): served live, left
        out of this recorder's file."""
        ch = self._relayed.get(topic)
        if ch is None:
            ch = self._relayed[topic] = self.fx.Channel(topic, schema=schema, message_encoding=encoding,
                                                         context=self.ctx, metadata={"relayed": f"robot_{robot}"})
        return ch

    def _robot(self, rid: int, topic: str):
        ch = self._by_robot.get((rid, topic))
        if ch is None:
            name = f"/robot_{{id}}/{topic}"
            ch = self._by_robot[(rid, topic)] = self.channel(name.replace("{id}", str(rid)), TOPICS[name])
        return ch

    def _json(self, ch, data: dict, ns: int) -> None:
        try:
            text = json.dumps(data, separators=(",", ":"), allow_nan=False, default=_plain)
        except ValueError:             # a NaN or inf: null in the JSON
            text = json.dumps(_finite(data), separators=(",", ":"), default=_plain)
        self._log(ch, text, ns)

    def _quat(self, yaw: float):
        return self.m.Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2.0), w=math.cos(yaw / 2.0))

    def _pose(self, x: float, y: float, yaw: float, z: float = 0.0):
        m = self.m
        return m.Pose(position=m.Vector3(x=float(x), y=float(y), z=float(z)), orientation=self._quat(yaw))

    # ------------------------------------------------------------------ what is recorded
    def _parts(self, key, pose) -> tuple:
        """(x, y, yaw), the protobuf of its position and orientation (:func:`_pose_pb`) and a PoseInFrame's fields
        after the timestamp, encoded once while ``key``'s pose stays the same (a robot standing still; the truth
        and its frame transform in a cycle)."""
        xyy = (float(pose[0]), float(pose[1]), float(pose[2]))
        last = self._parts_cache.get(key)
        if last is None or last[0] != xyy:
            vec, quat = _pose_pb(*xyy)
            last = self._parts_cache[key] = (xyy, vec, quat, _WORLD_PB + _POSE_HEAD + vec + _QUAT_IN_POSE + quat)
        return last

    def _pb_stamp(self, ns: int) -> bytes:
        """The timestamp field (1) of a message at ``ns``, encoded once a cycle."""
        if ns != self._pb_ts_ns:
            self._pb_ts_ns, self._pb_ts = ns, _field(1, _timestamp_pb(ns))
        return self._pb_ts

    def pose(self, rid: int, now: float, pose, truth: bool = False) -> None:
        """The robot's pose ``(x, y, yaw)`` (its estimate, or with ``truth`` the simulation's) as a
        ``foxglove.PoseInFrame`` in the world frame."""
        ns = self.stamp(now)
        self._log(self._robot(rid, "truth" if truth else "pose"), self._pb_stamp(ns) + self._parts((rid, truth),
                                                                                                  pose)[3], ns)

    def transforms(self, now: float, poses) -> None:
        """The world -> robot_N frame of each ``(rid, pose)`` (the truth in SITL), one ``foxglove.FrameTransforms``
        for them all."""
        ns = self.stamp(now)
        head = self._pb_stamp(ns) + _WORLD_PB
        tfs = []
        for rid, pose in poses:
            _, vec, quat, _ = self._parts((rid, True), pose)
            tfs.append(_field(1, head + _field(3, f"robot_{rid}".encode()) + _TRANSLATION + vec + _ROTATION + quat))
        self._log(self.channel("/tf", TOPICS["/tf"]), b"".join(tfs), ns)

    def path(self, rid: int, now: float, points) -> None:
        ns = self.stamp(now)
        m = self.m
        poses = [self._pose(p[0], p[1], 0.0) for p in points or ()]
        self._log(self._robot(rid, "path"), m.PosesInFrame(timestamp=self._ts(ns), frame_id=WORLD, poses=poses), ns)

    def command(self, rid: int, now: float, v: float, w: float) -> None:
        v, w = float(v), float(w)
        if math.isfinite(v) and math.isfinite(w):      # every cycle: the JSON written out by hand
            self._log(self._robot(rid, "command"), f'{{"robot":{int(rid)},"v":{v!r},"w":{w!r}}}', self.stamp(now))
        else:
            self._json(self._robot(rid, "command"), {"robot": rid, "v": v, "w": w}, self.stamp(now))

    def ranges(self, rid: int, now: float, ranges) -> None:
        """``(bearing, distance)`` pairs in the robot's frame, as points in ``robot_{rid}``."""
        ns = self.stamp(now)
        m = self.m
        data = b"".join(struct.pack("<fff", d * math.cos(b), d * math.sin(b), 0.0) for b, d in ranges
                        if math.isfinite(b) and math.isfinite(d))
        f32 = m.PackedElementFieldNumericType.Float32
        fields = [m.PackedElementField(name=n, offset=4 * i, type=f32) for i, n in enumerate("xyz")]
        self._log(self._robot(rid, "ranges"), m.PointCloud(timestamp=self._ts(ns), frame_id=f"robot_{rid}",
                                                           point_stride=12, fields=fields, data=data), ns)

    def scan(self, rid: int, now: float, ranges, bins: int = SCAN_BINS) -> None:
        """A laser's ``(bearing, distance)`` pairs (robot frame) as one ``foxglove.LaserScan`` in ``robot_{rid}``:
        the schema wants ranges at equal steps, so each reading goes to its bin of ``bins`` over [-pi, pi) (the
        nearest, where two share one; an RPLIDAR A1's 360 readings a revolution each get their own at 360) and a
        bin with none is NaN (no return)."""
        ns = self.stamp(now)
        step = 2.0 * math.pi / bins
        out = [math.nan] * bins
        for b, d in ranges:
            if math.isfinite(b) and math.isfinite(d):
                i = int(round((math.remainder(b, 2.0 * math.pi) + math.pi) / step)) % bins
                if not d >= out[i]:          # NaN (empty) or farther: this one
                    out[i] = d
        m = self.m
        self._log(self._robot(rid, "scan"), m.LaserScan(timestamp=self._ts(ns), frame_id=f"robot_{rid}",
                                                        start_angle=-math.pi, end_angle=math.pi - step,
                                                        ranges=out), ns)

    def bumpers(self, rid: int, now: float, left: bool, right: bool, wheel_drop: bool, faults=()) -> None:
        self._json(self._robot(rid, "bumpers"), {"robot": rid, "left": bool(left), "right": bool(right),
                                                 "wheel_drop": bool(wheel_drop), "faults": list(faults)},
                   self.stamp(now))

    def stats(self, rid: int, now: float, snapshot: dict) -> None:
        self._json(self._robot(rid, "stats"), snapshot, self.stamp(now))

    def event(self, now: float, robot: int, event: str, message: str = "", task: int | None = None,
              robots=(), fields: dict | None = None, t: float | None = None) -> None:
        """One allocation event (see the ``mrta.AllocationEvent`` schema); ``t`` (default ``now``) is when it
        happened, for events told after the fact."""
        self._json(self.channel("/allocation", TOPICS["/allocation"]),
                   {"robot": robot, "event": event, "t": now if t is None else t, "task": task, "message": message,
                    "robots": list(robots), "fields": fields or {}}, self.stamp(now))

    def text(self, now: float, level: int, name: str, text: str, file: str = "", line: int = 0) -> None:
        """One log line (``level`` as Python logging's)."""
        ns = self.stamp(now)
        m = self.m
        lv = m.LogLevel
        level = lv.Error if level >= 40 else lv.Warning if level >= 30 else lv.Info if level >= 20 else lv.Debug
        self._log(self.channel("/log", TOPICS["/log"]),
                  m.Log(timestamp=self._ts(ns), level=level, message=text, name=name, file=file, line=line), ns)

    def frame_tap(self, rid: int) -> "FrameTap":
        """Robot ``rid``'s link tap: ``tap(direction, datagram, address, now)`` holds each raw frame for
        :meth:`check` to write with the robot's others as one ``mrta.MavlinkFrames``."""
        tap = self._taps.get(rid)
        if tap is None:
            tap = self._taps[rid] = FrameTap(self, rid)
        return tap

    def frame(self, rid: int, now: float, direction: str, data: bytes, address=None) -> None:
        """One raw MAVLink datagram of robot ``rid``'s link (``direction`` "tx" or "rx"; ``address`` (host, port)),
        as its tap takes it."""
        if self.mavlink:
            self.frame_tap(rid)(direction, data, address, now)

    def _write_frames(self) -> None:
        """The held raw frames, one message a robot, at the recording's latest time; each frame with its own time.
        The JSON is written out by hand, each frame's head once per direction and address."""
        self._frames_due = None
        heads = self._frame_heads
        ns = self._last_ns
        for rid, tap in self._taps.items():
            if not tap.held:
                continue
            pending, tap.held = tap.held, []
            items = []
            for t, direction, address, data in pending:
                t = int(round(t * 1e9))
                key = (direction, None if address is None else (address[0], address[1]))
                head = heads.get(key)
                if head is None:
                    addr = "" if address is None else f"{address[0]}:{int(address[1])}"
                    head = heads[key] = (f',"direction":"{"rx" if direction == "rx" else "tx"}",'
                                         f'"address":{json.dumps(addr)},"frame":"')
                items.append(f'{{"ns":{t}{head}{data.hex()}"}}')
            self._log(self._robot(rid, "mavlink"), f'{{"robot":{int(rid)},"frames":[{",".join(items)}]}}', ns)

    def scene(self, now: float, world, tasks=()) -> None:
        """The world (a WorldConfig, or None: no map) as scene entities: the arena's floor and walls, the
        obstacles, and ``tasks`` as ``(id, x, y, label, state)`` or ``(id, x, y, label, state, facts)`` places
        coloured by state (:data:`TASK_COLOURS`).  ``facts`` (a dict) says more about the thing at the place, each
        one a metadata pair of the entity: ``robots`` (who holds or carries it), ``weight`` and ``left`` (wu of an
        object to carry: the place's disc is as tall as the share left), ``on`` (a formation target: the robot
        standing on it), ``kind``."""
        ns = self.stamp(now)
        m = self.m
        ts = self._ts(ns)
        entities = [] if world is None else self._arena(world, ts)
        for tid, x, y, label, state, *more in tasks:
            facts = more[0] if more and more[0] else {}
            rgb = TASK_COLOURS.get(state, (0.8, 0.2, 0.8))
            height, text = 0.05, f"{label} {state}"
            robots = facts.get("robots")
            if robots:
                text += " " + "+".join(f"R{r}" for r in robots)
            weight, left = facts.get("weight"), facts.get("left")
            if weight:
                share = 1.0 if left is None else min(1.0, max(0.0, left / weight))
                height = 0.05 + 0.3 * share
                text += f" {weight:g} wu" if left is None else f" {left:.3g}/{weight:g} wu"
            if facts.get("on") is not None:
                text += f" (R{facts['on']} on it)"
            meta = [m.KeyValuePair(key="state", value=state), m.KeyValuePair(key="task", value=str(tid))]
            meta += [m.KeyValuePair(key=k, value=_fact(v)) for k, v in facts.items() if v is not None]
            entities.append(m.SceneEntity(
                timestamp=ts, frame_id=WORLD, id=f"task_{tid}", metadata=meta,
                cylinders=[m.CylinderPrimitive(pose=self._pose(x, y, 0.0, height / 2.0),
                                               size=m.Vector3(x=0.3, y=0.3, z=height),
                                               bottom_scale=1.0, top_scale=1.0, color=self._colour(rgb, 0.8))],
                texts=[m.TextPrimitive(pose=self._pose(x, y, 0.0, height + 0.25), billboard=True, font_size=14.0,
                                       scale_invariant=True, color=self._colour(rgb), text=text)]))
        self._log(self.channel("/world", TOPICS["/world"]), m.SceneUpdate(entities=entities), ns)

    def _colour(self, rgb, a: float = 1.0):
        return self.m.Color(r=rgb[0], g=rgb[1], b=rgb[2], a=a)

    def _cube(self, x, y, yaw, sx, sy, sz, rgb, a: float = 1.0):
        m = self.m
        return m.CubePrimitive(pose=self._pose(x, y, yaw, sz / 2.0), size=m.Vector3(x=float(sx), y=float(sy),
                                                                                      z=float(sz)),
                               color=self._colour(rgb, a))

    def _arena(self, world, ts) -> list:
        """The floor, the walls (when the world has them) and the box obstacles."""
        m, cube = self.m, self._cube
        sx, sy = world.size
        grey = (0.55, 0.55, 0.6)
        arena = [cube(0.0, 0.0, 0.0, sx, sy, 0.01, (0.92, 0.92, 0.92), 0.6)]
        if getattr(world, "walls", False):
            arena += [cube(0.0, sy / 2, 0.0, sx, 0.05, 0.3, grey), cube(0.0, -sy / 2, 0.0, sx, 0.05, 0.3, grey),
                      cube(sx / 2, 0.0, 0.0, 0.05, sy, 0.3, grey), cube(-sx / 2, 0.0, 0.0, 0.05, sy, 0.3, grey)]
        obstacles = [cube(ob.center[0], ob.center[1], getattr(ob, "yaw", 0.0), ob.size[0], ob.size[1],
                          float(getattr(ob, "height", 0.4)), (0.35, 0.35, 0.4))
                     for ob in world.obstacles if getattr(ob, "size", None) is not None]
        return [m.SceneEntity(timestamp=ts, frame_id=WORLD, id="arena", cubes=arena),
                m.SceneEntity(timestamp=ts, frame_id=WORLD, id="obstacles", cubes=obstacles)]

class FrameTap:
    """A link's ``tap`` (``tap(direction, datagram, address, now)``, every datagram it sends or takes): holds the
    frame with its time (``now``, the host's clock; the system's on a wall-clock recording) until the recorder
    writes the robot's held frames as one message.  One call and one append a datagram: a message each cost a
    third of the recording."""

    __slots__ = ("rec", "rid", "held", "wall")

    def __init__(self, rec: Recorder, rid: int):
        self.rec, self.rid, self.held, self.wall = rec, rid, [], rec.wall

    def __call__(self, direction: str, data: bytes, address, now: float) -> None:
        rec = self.rec
        if rec._frames_due is None:
            rec._frames_due = rec._last_ns + int(FRAME_BATCH * 1e9)
        self.held.append((time.time() if self.wall else now, direction, address, data))


def recoverable(exc: BaseException) -> bool:
    """An error the recording may end on while the robot runs on: an Exception, or a panic in the Rust library
    (pyo3's PanicException is a BaseException); never a signal's or the interpreter's own."""
    return isinstance(exc, Exception) or type(exc).__name__ == "PanicException"


def _not_relayed(channel) -> bool:
    """The file's channel filter: what a launcher relays from its daemons is in their own files."""
    return "relayed" not in (channel.metadata or {})


# Foxglove's PoseInFrame and FrameTransforms encoded here (protobuf, the schemas' own field numbers): building the
# SDK's message objects for every pose of every cycle was a third of the recording's cost.  A test checks the bytes
# decode to what the SDK's own messages say.
_F64 = struct.Struct("<BdBd").pack
_WORLD_PB = b"\x12\x05" + WORLD.encode()       # frame_id / parent_frame_id (field 2)
_POSE_HEAD = b"\x1a\x28\x0a\x12"               # PoseInFrame.pose (3, 40 bytes), Pose.position (1, 18 bytes)
_QUAT_IN_POSE = b"\x12\x12"                     # Pose.orientation (2, 18 bytes)
_TRANSLATION, _ROTATION = b"\x22\x12", b"\x2a\x12"   # FrameTransform.translation (4), .rotation (5)


def _pose_pb(x: float, y: float, yaw: float) -> tuple[bytes, bytes]:
    """A pose's Vector3 (x, y; z = 0) and Quaternion (about z) message bodies, 18 bytes each (-0.0 as 0.0: the
    same value the SDK's encoder leaves out)."""
    return _F64(0x09, x + 0.0, 0x11, y + 0.0), _F64(0x19, math.sin(yaw / 2.0) + 0.0, 0x21, math.cos(yaw / 2.0))


def _varint(n: int) -> bytes:
    out = bytearray()
    while n > 0x7F:
        out.append(0x80 | (n & 0x7F))
        n >>= 7
    out.append(n)
    return bytes(out)


def _field(number: int, body: bytes) -> bytes:
    """A length-delimited protobuf field."""
    return _varint(number << 3 | 2) + _varint(len(body)) + body


def _timestamp_pb(ns: int) -> bytes:
    """A google.protobuf.Timestamp of ``ns`` >= 0 (seconds 1, nanos 2; zeros left out, as the SDK does)."""
    sec, nsec = divmod(ns, 1_000_000_000)
    return (b"\x08" + _varint(sec) if sec else b"") + (b"\x10" + _varint(nsec) if nsec else b"")


def _fact(v) -> str:
    """A scene fact as a metadata value: robot lists as "3,4", numbers as they print."""
    if isinstance(v, (list, tuple)):
        return ",".join(str(x) for x in v)
    return f"{v:g}" if isinstance(v, float) else str(v)


def _plain(v):
    """JSON for what json does not know: tuples are lists already; enums and other objects as their text."""
    return getattr(v, "name", None) or str(v)


def _finite(v):
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_finite(x) for x in v]
    return v
