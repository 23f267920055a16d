"""iRobot Create 2 / Create (1) base driver over the Open Interface.

A thin shell around :mod:`runtime.drivers.create_oi_protocol`: it opens the link with
``serial.serial_for_url`` (a device path, a pty, ``socket://host:port`` and ``loop://`` all work),
starts the OI, streams bumps and wheel drops (7), OI mode (35), battery (group 3 = 21-26) and the
encoder counts (43, 44) on a Create 2 or distance (19) and angle (20) on a Create 1, and turns them
into :class:`Odometry` and :class:`BaseSensors`.  Velocity goes out as Drive Direct (145).  The
finite check, the clipping to the footprint and the watchdog are :class:`MobileBase`'s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal, Optional

from runtime.config.build import rng
from runtime.drivers import create_oi_protocol as P
from runtime.drivers.base import Footprint, MobileBase
from runtime.drivers.serial_link import SerialLink
from runtime.errors import InputError
from runtime.log import get_logger

STREAM_IDS = {"create2": (7, 35, 3, 43, 44), "create1": (7, 35, 3, 19, 20)}
RECOVER_AFTER = 1.0        # s the wheels must be down again before Safe/Full is asked for again
RECOVER_BACKOFF_MAX = 16.0  # s between attempts at most (a cliff, which is not streamed, may persist)


@dataclass(frozen=True)
class CreateOIConfig:
    """The robot config's ``base:`` section for ``type: create_oi``."""
    type: Literal["create_oi"] = "create_oi"
    model: Literal["create1", "create2"] = "create2"
    port: str = "loop://"            # any pyserial URL
    baudrate: Optional[int] = None   # None: model default (57600 / 115200)
    mode: Literal["safe", "full"] = "safe"
    watchdog: float = field(default=0.5, metadata=rng(0.05, 10.0))
    max_speed: float = field(default=0.5, metadata=rng(0.01, 0.5))   # m/s per wheel
    guard: Optional[float] = field(default=0.5, metadata=rng(0.05, 10.0))   # s: the stop guard's bound; null: none


class CreateOI(MobileBase):
    """Create 2 or Create 1 on one serial link; non-blocking, polled with the current time."""

    Config = CreateOIConfig
    input_period = P.STREAM_PERIOD

    @classmethod
    def from_config(cls, cfg: CreateOIConfig, robot_id=None) -> "CreateOI":
        return cls(cfg.port, model=cfg.model, baudrate=cfg.baudrate, mode=cfg.mode, watchdog=cfg.watchdog,
                   max_speed=cfg.max_speed, guard=cfg.guard, robot_id=robot_id)

    def __init__(self, port: str, model: str = "create2", baudrate: int | None = None, mode: str = "safe",
                 watchdog: float = 0.5, max_speed: float = 0.5, guard: float | None = None, robot_id=None):
        P.check_model(model)
        if mode not in ("safe", "full"):
            raise InputError(f"Create OI mode {mode!r}: expected 'safe' or 'full'")
        geometry = P.GEOMETRY[model]
        baudrate = geometry.default_baud if baudrate is None else baudrate
        P.baud_code(baudrate)                                  # must be an OI rate
        top = geometry.max_wheel_mm_s / 1000.0
        if not (isinstance(max_speed, (int, float)) and 0 < max_speed <= top):
            raise InputError(f"Create OI max_speed {max_speed!r}: expected 0 < m/s <= {top:g}")
        super().__init__(create_footprint(model, max_speed), watchdog, get_logger("create_oi", robot_id))
        self.port = port
        self.guard = guard
        self.model = model
        self.geometry = geometry
        self.baudrate = baudrate
        self.mode = mode
        self.stats.extra.update({"malformed": 0, "mode_recoveries": 0})
        self.link = SerialLink(port, baudrate, "Create OI", self.log, self.stats.extra)
        self.parser = P.StreamParser(model)
        self.values: dict = {}               # latest named values from the stream
        self._counts: tuple[int, int] | None = None
        self._reached_mode = False           # the base has reported self.mode since open()
        self._passive_since: float | None = None  # in an unwanted Passive with the wheels down, since
        self._mode_since: float | None = None     # in self.mode since
        self._backoff = RECOVER_AFTER

    @property
    def ser(self):
        """The open pyserial port (None when closed)."""
        return self.link.ser

    # ------------------------------------------------------------------ lifecycle
    def _open(self, now: float) -> None:
        """Open the link; Start, Safe or Full, then Stream the packets odometry needs."""
        self._counts = None
        self.link.open()
        self._write(P.start())
        self._write(P.safe() if self.mode == "safe" else P.full())
        self._write(P.stream(STREAM_IDS[self.model], self.model))
        self._reached_mode = False
        self._passive_since = self._mode_since = None
        self._backoff = RECOVER_AFTER
        self.odometry.t = now
        self.log.info("opened %s (%s, %d bit/s, %s mode)", self.port, self.model, self.baudrate, self.mode)

    def _close(self) -> None:
        """Zero velocity, pause the stream, Stop (Create 1 has no Stop: Start returns it to Passive)."""
        self._write(P.drive_direct(0, 0))
        self._write(P.pause_resume_stream(False))
        self._write(P.stop() if self.model == "create2" else P.start())
        self.link.close()

    def stop_bytes(self) -> tuple[bytes, bytes]:
        """Frozen daemon: Drive Direct 0 0 (the OI keeps it until the daemon drives again).  Dead daemon: Drive
        Direct 0 0, then Start, which leaves the OI in Passive, where it takes no drive command."""
        return P.drive_direct(0, 0), P.drive_direct(0, 0) + P.start()

    def port_fd(self) -> int | None:
        return self.link.fileno()

    # ------------------------------------------------------------------ polling
    def _read(self, now: float) -> bool:
        """Decode waiting frames into odometry and sensors; ask for Safe/Full again if due."""
        data = self.link.read_all()
        moved = False
        if data:
            frames = self.parser.feed(data)
            ds = dth = 0.0
            n = 0
            for frame in frames:
                step = self._odometry_step(frame)
                self._update_sensors(frame)
                if step is not None:
                    ds += step[0]
                    dth += step[1]
                    n += 1
            if n:
                self._integrate(ds, dth, n, now)
                moved = True
            self._sync_stats()
        self._recover_mode(now)
        return moved

    def _recover_mode(self, now: float) -> None:
        """In Safe mode a wheel drop or a cliff puts the base in Passive, where it ignores drive
        commands.  Once the wheels have been down for a while (RECOVER_AFTER s at first), ask for Safe
        (or Full) again.  If the base drops straight back (a cliff: not streamed), the wait doubles up to
        RECOVER_BACKOFF_MAX; it starts over after the base has held its mode for twice that long."""
        s = self.sensors
        if s.mode == self.mode:
            self._reached_mode = True
            self._passive_since = None
            if self._mode_since is None:
                self._mode_since = now
            elif now - self._mode_since > 2 * RECOVER_BACKOFF_MAX:
                self._backoff = RECOVER_AFTER
            return
        self._mode_since = None
        if s.mode != "passive" or not self._reached_mode or self.ser is None:
            return
        if s.wheel_drop:
            self._passive_since = None
            return
        if self._passive_since is None:
            self._passive_since = now
        elif now - self._passive_since >= self._backoff:
            self._write(P.safe() if self.mode == "safe" else P.full())
            self.stats.extra["mode_recoveries"] += 1
            self.log.warning("base in passive with its wheels down for %.1f s: asking for %s mode again",
                             now - self._passive_since, self.mode)
            self._passive_since = None
            self._backoff = min(2 * self._backoff, RECOVER_BACKOFF_MAX)

    def _odometry_step(self, frame: dict) -> tuple[float, float] | None:
        """(distance m, heading change rad) since the previous frame, or None (no motion data)."""
        if self.model == "create1":
            if "distance" not in frame or "angle" not in frame:
                return None
            return frame["distance"] / 1000.0, math.radians(frame["angle"])
        if "left_encoder_counts" not in frame or "right_encoder_counts" not in frame:
            return None
        counts = (frame["left_encoder_counts"], frame["right_encoder_counts"])
        previous, self._counts = self._counts, counts
        if previous is None:                   # the first frame only sets the reference
            return None
        mpc = self.geometry.mm_per_count / 1000.0
        dl = _delta16(counts[0], previous[0]) * mpc
        dr = _delta16(counts[1], previous[1]) * mpc
        return (dl + dr) / 2.0, (dr - dl) / (self.geometry.track_mm / 1000.0)

    def _integrate(self, ds: float, dth: float, frames: int, now: float) -> None:
        o = self.odometry
        o.advance(ds, dth)
        span = frames * P.STREAM_PERIOD        # the robot sends one frame per 15 ms
        o.v, o.w = ds / span, dth / span
        o.t = now

    def _update_sensors(self, frame: dict) -> None:
        self.values.update(frame)
        s = self.sensors
        if "bumps_wheel_drops" in frame:
            s.bump_left = frame["bump_left"]
            s.bump_right = frame["bump_right"]
            s.wheel_drop = bool(frame["wheel_drop_left"] or frame["wheel_drop_right"]
                                or frame.get("wheel_drop_caster", False))
        if "oi_mode" in frame:
            mode = P.MODE_NAMES.get(frame["oi_mode"], "unknown")
            if mode != s.mode:
                expected = s.mode in ("unknown", "off") or mode == self.mode
                (self.log.info if expected else self.log.warning)("OI mode %s -> %s", s.mode, mode)
                s.mode = mode
        if "voltage" in frame:
            s.voltage = frame["voltage"] / 1000.0
            s.current = frame["current"] / 1000.0
            s.battery_charge = frame["battery_charge"] / 1000.0
            s.battery_capacity = frame["battery_capacity"] / 1000.0

    def _sync_stats(self) -> None:
        p = self.parser
        self.stats.frames = p.frames
        self.stats.bad_checksum = p.bad_checksum
        self.stats.dropped_bytes = p.dropped_bytes
        self.stats.extra["malformed"] = p.malformed

    # ------------------------------------------------------------------ commands
    def _command(self, v: float, w: float, now: float) -> bool:
        """``(v, w)``, already within the footprint, as Drive Direct: wheel speeds rounded to mm/s."""
        half = self._footprint.track / 2.0
        left, right = v - w * half, v + w * half
        return self._send_wheels(round(right * 1000.0), round(left * 1000.0))

    def _send_wheels(self, right_mm_s: int, left_mm_s: int) -> bool:
        lim = self.geometry.max_wheel_mm_s
        right_mm_s, left_mm_s = max(-lim, min(lim, right_mm_s)), max(-lim, min(lim, left_mm_s))
        self._write(P.drive_direct(right_mm_s, left_mm_s))
        return (right_mm_s, left_mm_s) != (0, 0)

    def _write(self, data: bytes) -> None:
        self.link.write(data)


def create_footprint(model: str, max_speed: float | None = None) -> Footprint:
    """The footprint of a Create ``model`` from its geometry table; ``max_speed`` (m/s per wheel, default
    the hardware's 0.5) caps both wheels and with them the turn rate in place."""
    g = P.GEOMETRY[P.check_model(model)]
    track = g.track_mm / 1000.0
    speed = g.max_wheel_mm_s / 1000.0 if max_speed is None else float(max_speed)
    return Footprint(radius=g.radius_mm / 1000.0, track=track, max_speed=speed, max_turn_rate=2.0 * speed / track)


def _delta16(new: int, old: int) -> int:
    """Signed difference of two 16-bit counters, across a rollover either way."""
    return (new - old + 0x8000) % 0x10000 - 0x8000
