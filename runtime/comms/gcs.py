"""A minimal ground station: listens on the GCS UDP port and keeps each robot's latest telemetry.

Used by the SITL launcher to watch the fleet the way an operator's GCS would (it never reads daemon
internals): HEARTBEAT, GLOBAL_POSITION_INT, LOCAL_POSITION_NED and the allocation MRTA_STATUS.
"""
from __future__ import annotations

import socket
from dataclasses import dataclass, field

from runtime.comms import codec, dialect
from runtime.comms.link import parse_address
from runtime.comms.telemetry import NO_TASK
from runtime.log import get_logger




@dataclass
class RobotView:
    heartbeats: int = 0
    mav_type: int | None = None
    lat: float | None = None
    lon: float | None = None
    north: float | None = None
    east: float | None = None
    task: int | None = None
    converged: bool = False
    messages: int = 0


@dataclass
class GroundStation:
    address: str
    robots: dict[int, RobotView] = field(default_factory=dict)
    bad_frames: int = 0

    def __post_init__(self) -> None:
        host, port = parse_address(self.address, "ground station address")
        self.log = get_logger("gcs")
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind((host, port))
        self.sock.setblocking(False)
        mod = dialect.load()
        self.mav = mod.MAVLink(None, srcSystem=255, srcComponent=190)
        self.mav.robust_parsing = True

    def poll(self) -> int:
        """Drain the socket; returns how many messages were decoded."""
        n = 0
        while True:
            try:
                data, _ = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return n
            except OSError:
                return n
            try:
                msgs = self.mav.parse_buffer(data) or []
            except Exception:        # pymavlink raises on some malformed frames: count, go on
                self.bad_frames += 1
                continue
            for m in msgs:
                if m.get_type() == "BAD_DATA":
                    self.bad_frames += 1
                    continue
                n += 1
                self._on(m)

    def _on(self, m) -> None:
        view = self.robots.setdefault(m.get_srcSystem(), RobotView())
        view.messages += 1
        kind = m.get_type()
        if kind == "HEARTBEAT":
            view.heartbeats += 1
            view.mav_type = m.type
        elif kind == "GLOBAL_POSITION_INT":
            view.lat, view.lon = m.lat / 1e7, m.lon / 1e7
        elif kind == "LOCAL_POSITION_NED":
            view.north, view.east = m.x, m.y
        elif codec.is_agent(m):
            msg = codec.from_mavlink(m)
            if type(msg).__name__ == "Status":
                view.task = None if msg.task == NO_TASK else msg.task
                view.converged = bool(msg.converged)

    def status(self) -> dict[int, dict]:
        return {rid: {"task": v.task, "converged": v.converged, "east": v.east, "north": v.north}
                for rid, v in self.robots.items() if v.heartbeats}

    def close(self) -> None:
        self.sock.close()
