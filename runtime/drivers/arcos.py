"""Pioneer 3-DX (or any ARCOS robot server) base driver: the ARCOS client side, polled, never blocking.

A thin shell around :mod:`runtime.drivers.arcos_protocol`.  The link is any pyserial URL: the robot's
serial port, a pty, or ``socket://host:8101`` (MobileSim's and our emulator's TCP port).  ``open`` only
opens the link and sends SYNC0; :meth:`poll` carries the handshake on as ARIA's ``asyncConnectHandler``
does (each SYNC answered with the same id, else back to SYNC0, though a late answer to a step already passed is
ignored, so a round trip longer than the retry cannot livelock the handshake; SIPs still flowing from an earlier session:
CLOSE and start again; no answer: the SYNC again, and CLOSE every third miss to dislodge a confused
server), reads the name, class and subclass from the SYNC2 reply, then sends OPEN, ENABLE 1, SONAR and
CONFIG.

Velocity goes out as VEL (mm/s) and RVEL (deg/s), at most once per SIP cycle unless it is a stop; while
the robot moves the pair is re-sent every 0.5 s (ARIA's state reflection), and a PULSE goes out when
nothing else was sent for 0.5 s, so the robot's watchdog never fires while the daemon runs.  CLOSE on close.

Each standard SIP gives odometry (the robot's 15-bit XPOS/YPOS unwrapped as ARIA does, its heading in
4096ths of a turn, wheel velocities and ROTVEL), the sonar readings placed by the p3dx-sh sonar table as
bearing and distance from the centre (readings at the 5 m limit mean no echo), the stall and bumper bits
(a stall while not reversing counts as a bump on that side; front bumpers 1-2 left, 3 both, 4-5 right),
battery, motor, e-stop and fault flags.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from runtime.config.build import rng
from runtime.drivers import arcos_protocol as P
from runtime.drivers.base import Footprint, MobileBase
from runtime.drivers.serial_link import SerialLink
from runtime.errors import InputError
from runtime.log import get_logger

SYNC_RETRY = 0.25          # s without an answer before a SYNC is sent again
DISLODGE_EVERY = 3         # misses in a row: CLOSE, then SYNC0
SYNC_WARN_AFTER = 10.0     # s of handshake before a warning (MobileSim gives a handshake 10 s)
KEEPALIVE = 0.5            # s of silence before a PULSE (ArRobot.cpp: more than 500 ms)
REFRESH = 0.5              # s between re-sends of VEL + RVEL while moving (myStateReflectionRefreshTime)
MIN_MOTION_INTERVAL = 0.1  # s between motion updates (one SIP cycle); stops go at once
SIP_TIMEOUT = 3.0          # s without a SIP once connected: handshake again
SONAR_MAX_AGE = 1.0        # s a sonar reading stays in sensors.ranges (the P3-DX ring refreshes in ~0.32 s)
ENABLE_RETRY = 1.0         # s between ENABLE requests while the robot reports its motors disabled
FAULT_NAMES = {1: "high_temperature", 4: "gyro_fault"}    # FAULTFLAGS bits (MobileSim; ArAnalogGyro.cpp)


@dataclass(frozen=True)
class ArcosConfig:
    """The robot config's ``base:`` section for ``type: arcos``."""
    type: Literal["arcos"] = "arcos"
    port: str = "/dev/ttyUSB0"          # any pyserial URL, e.g. socket://127.0.0.1:8101
    baudrate: int = field(default=9600, metadata=rng(300, 921600))   # ARCOS starts at 9600
    subclass: Literal["p3dx-sh"] = "p3dx-sh"      # the ARIA parameter file the numbers come from
    watchdog: float = field(default=0.5, metadata=rng(0.05, 10.0))
    max_speed: float = field(default=0.75, metadata=rng(0.01, 2.2))  # m/s per wheel
    sonar: bool = True


class ArcosBase(MobileBase):
    """One ARCOS robot on one link; non-blocking, polled with the current time."""

    Config = ArcosConfig
    ranging = True             # the sonar ring
    input_period = 0.1         # s: one SIP per cycle (the P3-DX's default, as MobileSim's)

    @property
    def sensor_kinds(self) -> tuple[str, ...]:
        return ("sonar",) if self.want_sonar else ()

    @classmethod
    def from_config(cls, cfg: ArcosConfig, robot_id=None) -> "ArcosBase":
        return cls(cfg.port, baudrate=cfg.baudrate, subclass=cfg.subclass, watchdog=cfg.watchdog,
                   max_speed=cfg.max_speed, sonar=cfg.sonar, robot_id=robot_id)

    def __init__(self, port: str, baudrate: int = 9600, subclass: str = "p3dx-sh", watchdog: float = 0.5,
                 max_speed: float = 0.75, sonar: bool = True, robot_id=None):
        params = P.robot_params(subclass)
        top = params.max_vel_mm_s / 1000.0
        if not (isinstance(max_speed, (int, float)) and 0 < max_speed <= top):
            raise InputError(f"ARCOS max_speed {max_speed!r}: expected 0 < m/s <= {top:g}")
        super().__init__(arcos_footprint(params, max_speed), watchdog, get_logger("arcos", robot_id))
        self.params = params
        self.port = port
        self.want_sonar = bool(sonar)
        self.stats.extra.update({k: 0 for k in (
            "bad_count", "stale_headers", "bad_sip", "bad_sonar", "other_packets", "handshakes", "sync_restarts", "sync_resends",
            "late_sync_replies",
            "stale_sessions", "reconnects", "pulses", "motion_commands", "enable_requests")})
        self.link = SerialLink(port, baudrate, "ARCOS", self.log, self.stats.extra)
        self.parser = P.PacketParser()
        self.state = "closed"               # closed | sync | connected
        self.identity: tuple[str, str, str] | None = None     # (name, class, subclass) from SYNC2
        self.config_pac: dict | None = None
        self.last_sip: P.Sip | None = None
        self._reset_session(0.0)

    def _reset_session(self, now: float) -> None:
        self._expect = 0
        self._sync_sent = now
        self._sync_started = now
        self._misses = 0
        self._sync_warned = False
        self._last_close = -math.inf
        self._last_tx = now
        self._last_motion_tx = -math.inf
        self._sent_motion: tuple[int, int] | None = None
        self._target = (0, 0)
        self._last_sip_t = now
        self._last_enable = -math.inf
        self._connected_at = now
        self._pose_ref: tuple[int, int, int] | None = None    # the previous SIP's raw x, y, th
        self._xy = [0.0, 0.0]                                 # unwrapped robot-frame position, mm
        self._th0 = 0.0
        self._sonar: dict[int, tuple[float, float]] = {}      # sonar number -> (range mm, time)

    # ------------------------------------------------------------------ lifecycle
    def _open(self, now: float) -> None:
        self.parser = P.PacketParser()
        self.link.open()
        self._reset_session(now)
        self.state = "sync"
        self.sensors.mode = "sync"
        self.odometry.t = now
        self._send(P.sync(0), now)
        self.log.info("opened %s (%d bit/s): handshake", self.port, self.link.baudrate)

    def _close(self) -> None:
        """STOP and CLOSE (the robot server closes and stops the motors), then the link."""
        if self.state == "connected":
            self._send(P.stop(), self._last_tx)
        self._send(P.close(), self._last_tx)
        self.link.close()
        self.state = "closed"
        self.sensors.mode = "closed"

    def stop_bytes(self) -> tuple[bytes, bytes]:
        """VEL 0 and RVEL 0; for a dead daemon then STOP and CLOSE (the server ends the session, motors stopped).
        The robot's own watchdog stops it anyway, after its watchdog time (2 s on a P3-DX)."""
        return P.vel(0) + P.rvel(0), P.vel(0) + P.rvel(0) + P.stop() + P.close()

    def port_fd(self) -> int | None:
        return self.link.fileno()

    # ------------------------------------------------------------------ polling
    def _read(self, now: float) -> bool:
        fresh = False
        data = self.link.read_all()
        if data:
            for body in self.parser.feed(data):
                fresh |= self._on_packet(body, now)
            self._sync_stats()
        if self.state == "sync":
            self._sync_timer(now)
        elif self.state == "connected":
            self._keep_alive(now)
        return fresh

    def _on_packet(self, body: bytes, now: float) -> bool:
        pid = body[0]
        if self.state == "sync":
            self._on_sync_packet(body, now)
            return False
        if pid in P.SIP_IDS:
            try:
                sip = P.decode_sip(body)
            except P.SipError as exc:
                self.stats.extra["bad_sip"] += 1
                if self.stats.extra["bad_sip"] in (1, 10, 100):
                    self.log.warning("bad SIP: %s", exc)
                return False
            return self._on_sip(sip, now)
        if pid == P.CONFIG_PAC:
            self.config_pac = P.decode_config(body)
            self.log.info("CONFIGpac: %s %s serial %r firmware %r, watchdog %s ms, SIP cycle %s ms",
                          self.config_pac.get("robot_class"), self.config_pac.get("subclass"),
                          self.config_pac.get("serial"), self.config_pac.get("firmware"),
                          self.config_pac.get("watchdog_ms"), self.config_pac.get("sip_cycle_ms"))
            return False
        self.stats.extra["other_packets"] += 1
        return False

    # ------------------------------------------------------------------ handshake
    def _on_sync_packet(self, body: bytes, now: float) -> None:
        pid = body[0]
        x = self.stats.extra
        if pid in P.SIP_IDS:                      # a session is still open: close it, start again
            if now - self._last_close > SYNC_RETRY:
                x["stale_sessions"] += 1
                self.log.info("SIPs still flowing from an earlier session: CLOSE and SYNC0 again")
                self._send(P.close(), now)
                self._last_close = now
                self._restart(now)
            return
        if pid < self._expect:                   # a late answer to a SYNC re-sent before its first answer came
            x["late_sync_replies"] += 1          # (a round trip over SYNC_RETRY): that step is done, wait on
            return
        if pid != self._expect:
            x["sync_restarts"] += 1
            self._restart(now)
            return
        if pid < 2:
            self._expect += 1
            self._misses = 0
            self._send_sync(now)
            return
        self.identity = P.parse_sync2(body)
        x["handshakes"] += 1
        name, cls, sub = self.identity
        (self.log.info if sub == self.params.subclass else self.log.warning)(
            "connected to %r: %s %s after %.2f s (configured for %s)", name, cls, sub, now - self._sync_started,
            self.params.subclass)
        self.state = "connected"
        self._connected_at = self._last_sip_t = now
        self._sent_motion = (0, 0)                # the server starts still
        self._send(P.open_(), now)
        self._send(P.enable(True), now)
        self._last_enable = now
        self._send(P.sonar(self.want_sonar), now)
        self._send(P.config(), now)
        self.sensors.mode = "disabled"

    def _restart(self, now: float) -> None:
        self._expect = 0
        self._misses = 0
        self._send_sync(now)

    def _send_sync(self, now: float) -> None:
        self._send(P.sync(self._expect), now)
        self._sync_sent = now

    def _sync_timer(self, now: float) -> None:
        if now - self._sync_sent < SYNC_RETRY:
            return
        self._misses += 1
        self.stats.extra["sync_resends"] += 1
        if self._misses % DISLODGE_EVERY == 0:
            self._send(P.close(), now)
            self._expect = 0
        self._send_sync(now)
        if not self._sync_warned and now - self._sync_started > SYNC_WARN_AFTER:
            self._sync_warned = True
            self.log.warning("no ARCOS handshake on %s after %.0f s: still trying", self.port, now - self._sync_started)

    # ------------------------------------------------------------------ connected
    def _keep_alive(self, now: float) -> None:
        if now - self._last_sip_t > SIP_TIMEOUT:
            self.stats.extra["reconnects"] += 1
            self.log.warning("no SIP for %.1f s: handshake again", now - self._last_sip_t)
            self._reset_session(now)
            self.state = "sync"
            self.sensors.mode = "sync"
            self._send_sync(now)
            return
        self._flush_motion(now)
        sip = self.last_sip
        if (sip is not None and not sip.flags & P.FLAG_MOTORS and not sip.flags & P.FLAG_ESTOP
                and now - self._last_enable >= ENABLE_RETRY):
            self.stats.extra["enable_requests"] += 1
            self._send(P.enable(True), now)
            self._last_enable = now
        if now - self._last_tx >= KEEPALIVE:
            self.stats.extra["pulses"] += 1
            self._send(P.pulse(), now)

    def _on_sip(self, sip: P.Sip, now: float) -> bool:
        self.last_sip = sip
        self._last_sip_t = now
        self._odometry(sip, now)
        self._sonars(sip, now)
        self._status(sip, now)
        return True

    def _odometry(self, sip: P.Sip, now: float) -> None:
        pr = self.params
        o = self.odometry
        if self._pose_ref is None:
            self._th0 = sip.th * pr.angle_conv
            dx = dy = 0
        else:
            dx = P.wrap15(sip.x - self._pose_ref[0])
            dy = P.wrap15(sip.y - self._pose_ref[1])
        self._pose_ref = (sip.x, sip.y, sip.th)
        self._xy[0] += dx * pr.dist_conv
        self._xy[1] += dy * pr.dist_conv
        c, s = math.cos(self._th0), math.sin(self._th0)
        o.x = (c * self._xy[0] + s * self._xy[1]) / 1000.0          # in the frame of the first SIP
        o.y = (-s * self._xy[0] + c * self._xy[1]) / 1000.0
        o.theta = math.remainder(sip.th * pr.angle_conv - self._th0, math.tau)
        o.distance += math.hypot(dx, dy) * pr.dist_conv / 1000.0
        left, right = sip.left_vel * pr.vel_conv, sip.right_vel * pr.vel_conv
        o.v = (left + right) / 2000.0
        o.w = (math.radians(sip.rot_vel_x10 / 10.0) if sip.rot_vel_x10 is not None
               else (right - left) / 2.0 * pr.diff_conv)
        o.t = now

    def _sonars(self, sip: P.Sip, now: float) -> None:
        pr = self.params
        units = len(pr.sonar_units)
        for num, rng_raw in sip.sonars:
            if num >= units:
                self.stats.extra["bad_sonar"] += 1
                continue
            self._sonar[num] = (rng_raw * pr.range_conv, now)
        arrays = (sip.flags & P.FLAG_SONAR_ARRAYS[0], sip.flags & P.FLAG_SONAR_ARRAYS[1])
        out = []
        for num in sorted(self._sonar):
            r, t = self._sonar[num]
            if not arrays[0 if num in P.FRONT_SONARS else 1] or now - t > SONAR_MAX_AGE:
                continue
            if r < pr.sonar_max_range_mm:
                out.append(pr.sonar_point(num, r))
        self.sensors.ranges = tuple(out)

    def _status(self, sip: P.Sip, now: float) -> None:
        s = self.sensors
        bits = sip.stall_bumpers
        front = (bits >> 9) & 0x1F                        # front bumpers 1..5, bit 0 = bumper 1 (leftmost)
        forward = self._target[0] >= 0
        s.bump_left = bool((bits & P.LEFT_STALL and forward) or front & 0b00111)
        s.bump_right = bool((bits & P.RIGHT_STALL and forward) or front & 0b11100)
        volts = sip.battery_x10 / 10.0 if sip.battery_x10 else sip.battery_dv / 10.0
        s.voltage = volts
        if sip.state_of_charge:
            s.battery_charge, s.battery_capacity = float(sip.state_of_charge), 100.0   # percent
        estop = bool(sip.flags & P.FLAG_ESTOP)
        motors = bool(sip.flags & P.FLAG_MOTORS)
        mode = "estop" if estop else "enabled" if motors else "disabled"
        if mode != s.mode:
            (self.log.info if mode == "enabled" or s.mode == "sync" else self.log.warning)(
                "robot %s -> %s", s.mode, mode)
            s.mode = mode
        faults = ["estop"] if estop else []
        if not motors and not estop and now - self._connected_at > 2 * ENABLE_RETRY:
            faults.append("motors_disabled")
        for bit in range(16):
            if (sip.fault_flags or 0) >> bit & 1:
                faults.append(FAULT_NAMES.get(bit, f"fault_flag_{bit}"))
        s.faults = tuple(faults)

    # ------------------------------------------------------------------ commands
    def _command(self, v: float, w: float, now: float) -> bool:
        """``(v, w)`` as VEL mm/s and RVEL deg/s, rounded; sent now if it is a stop or the last motion update
        is a SIP cycle old (or the robot is still), else at the next poll that is."""
        pr = self.params
        mm = max(-pr.max_vel_mm_s, min(pr.max_vel_mm_s, round(v * 1000.0)))
        deg = max(-pr.max_rvel_deg_s, min(pr.max_rvel_deg_s, round(math.degrees(w))))
        self._target = (int(mm), int(deg))
        if self.state == "connected":
            self._flush_motion(now)
        return self._target != (0, 0)

    def _flush_motion(self, now: float) -> None:
        target, sent = self._target, self._sent_motion
        since = now - self._last_motion_tx
        if target != sent:
            due = (0, 0) in (target, sent) or sent is None or since >= MIN_MOTION_INTERVAL
        else:
            fresh = self._last_cmd_t is not None and now - self._last_cmd_t < self.watchdog
            due = target != (0, 0) and since >= REFRESH and fresh     # not a refresh the watchdog would undo
        if due:
            self._send(P.vel(target[0]) + P.rvel(target[1]), now)
            self.stats.extra["motion_commands"] += 1
            self._sent_motion = target
            self._last_motion_tx = now

    def _send(self, data: bytes, now: float) -> None:
        self.link.write(data)
        self._last_tx = now

    def _sync_stats(self) -> None:
        p = self.parser
        self.stats.frames = p.packets
        self.stats.bad_checksum = p.bad_checksum
        self.stats.dropped_bytes = p.dropped_bytes
        self.stats.extra["bad_count"] = p.bad_count
        self.stats.extra["stale_headers"] = p.stale_headers


def arcos_footprint(params: P.RobotParams = P.P3DX_SH, max_speed: float | None = None) -> Footprint:
    """The footprint from a robot parameter file: RobotRadius, the DiffConvFactor track, ``max_speed`` per wheel
    (default the hardware's MaxVelocity) and the turn rate in place it allows, at most MaxRVelocity."""
    track = params.track_mm / 1000.0
    speed = params.max_vel_mm_s / 1000.0 if max_speed is None else float(max_speed)
    turn = min(2.0 * speed / track, math.radians(params.max_rvel_deg_s))
    return Footprint(radius=params.radius_mm / 1000.0, track=track, max_speed=speed, max_turn_rate=turn)
