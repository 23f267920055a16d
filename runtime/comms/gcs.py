"""A minimal ground station: one UDP socket that watches a fleet and hands it missions.

The SITL launcher uses it to be the fleet's operator (it never reads daemon internals), and ``mrta mission
status`` to ask a robot for the fleet's tasks.  Like QGC or MAVProxy it sends a HEARTBEAT (MAV_TYPE_GCS) to
the robots it knows once a second, so they stream their telemetry to it wherever it listens; by default
it listens on a port of its own, leaving the fleet's configured ground-station port to a stock GCS.  It keeps per robot what the robot reports (HEARTBEAT,
positions, :class:`~runtime.messages.RobotState`, MISSION_ITEM_REACHED, MISSION_CURRENT, STATUSTEXT)
and a copy of the fleet's task table from the robots' answers to its table requests; it runs the mission
protocol's ground side (:class:`~runtime.comms.mission.MissionClient`) for uploads, one per robot at a
time.

What it reads it validates, counting every datagram once in :attr:`GroundStation.counters` (a
:class:`~runtime.comms.link.LinkCounters`: ``datagrams == received + dropped``, ``kernel_dropped`` for what a
flood made the kernel drop) and every refused frame in ``frames_dropped``:

* frames that do not decode (junk, bad CRC, cut short) or whose values the protocol does not allow (the codec's
  ``invalid()``; task ids whose origin robot, and holders, are no robot of the fleet) are ``parse_errors``,
  ``bad_crc``, ``invalid``;
* frames from a system that is no robot of the fleet (when it was given its robots) are ``not_for_us``;
* with a signing key, robot frames count only if signed with the key on the robots' ground-station link id
  (:data:`~runtime.comms.link.GCS_LINK`): unsigned, wrongly signed and replayed frames (an old timestamp, or a
  frame a robot sent to its peers) are ``unsigned_dropped``, ``bad_signature_dropped``, ``replayed_dropped``.
  So the status a verdict is built on is authenticated.  Without a key anyone who can reach the port can
  forge a fleet robot's status within the protocol's ranges: an unsigned fleet is an explicit choice.
"""
from __future__ import annotations

import math
import re
import socket
import time
from collections import deque
from dataclasses import dataclass, field

from runtime.comms import codec, dialect, udp
from runtime.comms.link import (GCS_LINK, KERNEL_DROPS_PERIOD, MAX_DATAGRAMS_PER_POLL, MAX_ROBOT_ID, OPERATOR_LINK, LinkCounters, count_datagram,
                                parse_datagram, parse_address, refusal, signing_guard, signing_timestamp)
from runtime.comms.mission import MissionClient
from runtime.errors import InputError
from runtime.messages import RobotState, TableRequest, TaskRecord
from runtime.log import get_logger

GCS_SYSTEM, GCS_COMPONENT = 255, 190      # MAVProxy's and QGC's ground-station ids
HEARTBEAT_PERIOD = 1.0
MAX_TEXTS = 1000          # STATUSTEXT lines kept per robot
REACHED_TEXT = re.compile(r"task (\d{1,5})\.(\d{1,5}) reached\Z")      # a robot arrived at a fleet task
MAX_CHUNKED = 8           # chunked STATUSTEXT lines being reassembled per robot


def ground_mav(signing_key: bytes | None = None, link_id: int = OPERATOR_LINK):
    """The fleet dialect's module and a MAVLink encoder/parser with a ground station's ids, signing with
    ``signing_key`` (its own ``link_id``: see :mod:`runtime.comms.link`) when given."""
    module = dialect.load()
    mav = signing_guard(module.MAVLink)(None, srcSystem=GCS_SYSTEM, srcComponent=GCS_COMPONENT)
    mav.robust_parsing = True
    if signing_key is not None:
        s = mav.signing
        s.secret_key, s.sign_outgoing, s.link_id = bytes(signing_key), True, int(link_id)
        s.timestamp = signing_timestamp(time.time())
    return module, mav


def gcs_heartbeat(module, mav):
    """A ground station's HEARTBEAT (MAV_TYPE_GCS): robots stream their telemetry to whoever sends it."""
    return mav.heartbeat_encode(module.MAV_TYPE_GCS, module.MAV_AUTOPILOT_INVALID, 0, 0, module.MAV_STATE_ACTIVE)


@dataclass
class RobotView:
    heartbeats: int = 0
    mav_type: int | None = None
    base_mode: int = 0
    lat: float | None = None
    lon: float | None = None
    north: float | None = None
    east: float | None = None
    state: int | None = None           # RobotState.state
    tasks: tuple[int, ...] = ()        # fleet task ids it holds
    heard: float = -math.inf           # when its last RobotState came
    messages: int = 0
    reached: list[int] = field(default_factory=list)     # MISSION_ITEM_REACHED seqs: the fleet's items done
    arrived: list[int] = field(default_factory=list)     # fleet task ids this robot said it reached (STATUSTEXT)
    texts: deque = field(default_factory=lambda: deque(maxlen=MAX_TEXTS))      # (time, line)
    chunks: dict[int, dict[int, str]] = field(default_factory=dict)   # STATUSTEXT id -> chunk_seq -> text
    current: int | None = None         # MISSION_CURRENT.seq


@dataclass
class Upload:
    robot: int
    address: tuple
    client: MissionClient
    started: float


class GroundStation:
    def __init__(self, address: str = "127.0.0.1:0", *, robots: dict[int, tuple] | None = None,
                 signing_key: bytes | None = None):
        host, port = parse_address(address, "ground station address", allow_port_zero=True)
        self.log = get_logger("gcs")
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind((host, port))
        except OSError as e:
            self.sock.close()
            raise InputError(f"ground station: cannot bind {address!r} ({e.strerror})") from None
        self.address = "%s:%d" % self.sock.getsockname()[:2]
        self.targets: dict[int, tuple] = dict(robots or {})     # robot -> its MAVLink address (heartbeats)
        self._next_heartbeat = -math.inf
        self.sock.setblocking(False)
        self._overflows = udp.count_overflows(self.sock)
        self._next_kernel_check = -math.inf
        self.module, self.mav = ground_mav(signing_key)
        self.signing = signing_key is not None
        self.robots: dict[int, RobotView] = {}
        self.table: dict[int, TaskRecord] = {}       # fleet task id -> the latest record heard
        self.uploads: dict[int, Upload] = {}         # robot -> its upload in flight
        self.finished: list[Upload] = []
        self.counters = LinkCounters()
        self.now = 0.0

    @property
    def bad_frames(self) -> int:
        """Frames (and runs of junk) refused so far."""
        return self.counters.frames_dropped

    # ------------------------------------------------------------------ sending
    def send(self, msg, address: tuple) -> None:
        if not hasattr(msg, "pack"):
            msg = codec.to_mavlink(msg, self.module)
        s = self.mav.signing
        if s.sign_outgoing:              # never behind the wall clock, as the robots' links
            s.timestamp = max(s.timestamp, signing_timestamp(time.time()))
        try:
            self.sock.sendto(msg.pack(self.mav), address)
        except OSError as e:
            self.log.debug("send to %s failed: %s", address, e)
        self.mav.seq = (self.mav.seq + 1) % 256

    def upload(self, robot: int, address: tuple, items: list, now: float) -> Upload:
        """Start uploading mission ``items`` to ``robot`` at ``address`` (it must have none in flight)."""
        if robot in self.uploads:
            raise RuntimeError(f"robot {robot} has an upload in flight")
        client = MissionClient(self.mav, robot, 1)
        up = Upload(robot, address, client, now)
        self.uploads[robot] = up
        for m in client.start_upload(items, now=now):
            self.send(m, address)
        return up

    def request_table(self, robot: int, address: tuple) -> None:
        """Ask ``robot`` for the fleet's task table (with holders); the answer updates :attr:`table`."""
        self.send(TableRequest(GCS_SYSTEM, robot, 0), address)

    # ------------------------------------------------------------------ receiving
    def poll(self, now: float | None = None) -> int:
        """Heartbeat the robots when due, drain the socket, drive the uploads; returns how many messages were
        decoded."""
        if now is not None:
            self.now = now
        if self.now >= self._next_heartbeat:
            self._next_heartbeat = self.now + HEARTBEAT_PERIOD
            hb = gcs_heartbeat(self.module, self.mav)
            for address in self.targets.values():
                self.send(hb, address)
        n = 0
        c = self.counters
        for data, _ in udp.datagrams(self.sock, self._overflows, c, MAX_DATAGRAMS_PER_POLL):
            msgs, refused = parse_datagram(self.mav, self.module, data)
            taken = False
            for m in msgs:
                why = self._take(m)
                if why is None:
                    taken = True
                    n += 1
                else:
                    refused.append(why)
            count_datagram(c, taken, refused)
        if self.now >= self._next_kernel_check:
            self._next_kernel_check = self.now + KERNEL_DROPS_PERIOD
            c.kernel_dropped = max(c.kernel_dropped, udp.proc_drops(self.sock) or 0)
        for up in list(self.uploads.values()):
            for m in up.client.tick(self.now):
                self.send(m, up.address)
            self._settle(up)
        return n

    def _statustext(self, view: RobotView, m) -> None:
        """A line of text: whole, or reassembled from MAVLink 2 chunks (same ``id``, a short last chunk)."""
        text = m.text if isinstance(m.text, str) else bytes(m.text).decode(errors="replace")
        text = text.split("\0", 1)[0]
        key = getattr(m, "id", 0)
        if not key:
            view.texts.append((self.now, text))
            arrived = REACHED_TEXT.match(text)            # the robot's own arrival (runtime.fleet.node's notice)
            if arrived:
                view.arrived.append(int(arrived[1]) << 16 | int(arrived[2]))
            return
        if key not in view.chunks and len(view.chunks) >= MAX_CHUNKED:
            del view.chunks[next(iter(view.chunks))]          # the oldest line never finished
        parts = view.chunks.setdefault(key, {})
        parts[getattr(m, "chunk_seq", 0)] = text
        if len(text) < 50:
            view.texts.append((self.now, "".join(parts[k] for k in sorted(parts))))
            del view.chunks[key]

    def _settle(self, up: Upload) -> None:
        if up.client.done and self.uploads.get(up.robot) is up:
            del self.uploads[up.robot]
            self.finished.append(up)

    def _take(self, m) -> str | None:
        """One decoded frame: None if taken, else the counter of why not."""
        kind = m.get_type()
        if kind == "BAD_DATA":
            return refusal(m)
        if kind.startswith("UNKNOWN"):
            return "unknown"
        src = m.get_srcSystem()
        if not 1 <= src <= MAX_ROBOT_ID:
            return "ignored"                     # another ground station, or our own echo
        if self.targets and src not in self.targets:
            return "not_for_us"                  # no robot of this fleet
        if self.signing and m.get_link_id() != GCS_LINK:
            return "replayed_dropped"            # signed for the robot's peers (pymavlink refused unsigned ones)
        try:
            self._on(m)
        except (codec.InvalidMessage, ValueError, TypeError, AttributeError, KeyError, IndexError):
            return "invalid"
        return None

    def _fleet_task(self, task: int) -> bool:
        """A fleet task id minted by a robot of the fleet (any robot id when the fleet is not known)."""
        origin = task >> 16
        return origin in self.targets if self.targets else 1 <= origin <= MAX_ROBOT_ID

    def _check(self, msg) -> None:
        """Values the codec cannot judge alone: task ids and holders must belong to this fleet."""
        tasks = msg.tasks if isinstance(msg, RobotState) else (msg.task,)
        if not all(self._fleet_task(t) for t in tasks):
            raise codec.InvalidMessage(f"task ids {list(tasks)}: expected tasks of this fleet's robots")
        holders = getattr(msg, "holders", ())
        if self.targets and not set(holders) <= set(self.targets):
            raise codec.InvalidMessage(f"holders {list(holders)}: expected robots of this fleet")

    def _on(self, m) -> None:
        src = m.get_srcSystem()
        kind = m.get_type()
        msg = codec.from_mavlink(m) if codec.is_agent(m) else None
        if isinstance(msg, (RobotState, TaskRecord)):
            self._check(msg)
        view = self.robots.setdefault(src, RobotView())
        view.messages += 1
        if kind == "HEARTBEAT":
            view.heartbeats += 1
            view.mav_type, view.base_mode = m.type, m.base_mode
        elif kind == "GLOBAL_POSITION_INT":
            view.lat, view.lon = m.lat / 1e7, m.lon / 1e7
        elif kind == "LOCAL_POSITION_NED":
            view.north, view.east = m.x, m.y
        elif kind == "MISSION_ITEM_REACHED":
            view.reached.append(int(m.seq))
        elif kind == "MISSION_CURRENT":
            view.current = int(m.seq)
        elif kind == "STATUSTEXT":
            self._statustext(view, m)
        elif kind.startswith("MISSION_") and src in self.uploads:
            up = self.uploads[src]
            for reply in up.client.handle(m, self.now):
                self.send(reply, up.address)
            self._settle(up)
        elif msg is not None:
            if isinstance(msg, RobotState):
                view.state, view.tasks, view.heard = msg.state, tuple(msg.tasks), self.now
            elif isinstance(msg, TaskRecord):
                old = self.table.get(msg.task)
                if old is None or msg.state >= old.state:
                    self.table[msg.task] = msg

    # ------------------------------------------------------------------ views
    def status(self, max_age: float = math.inf) -> dict[int, dict]:
        """Robots heard (RobotState within ``max_age`` s): state, tasks, position."""
        return {rid: {"state": v.state, "tasks": v.tasks, "east": v.east, "north": v.north, "heard": v.heard}
                for rid, v in self.robots.items() if v.state is not None and self.now - v.heard <= max_age}

    def close(self) -> None:
        self.sock.close()
