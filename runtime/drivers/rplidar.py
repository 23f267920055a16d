"""Slamtec RPLIDAR A1/A2 laser scanner driver: polled, never blocking, never raising out of :meth:`Rplidar.poll`.

A thin shell around :mod:`runtime.drivers.rplidar_protocol` on any pyserial URL (``serial.serial_for_url``: the
scanner's USB serial adapter, a pty, ``socket://``, ``loop://``).  :meth:`Rplidar.open` opens the port, asks the
motor to run (A1: DTR low, where the port has modem lines; A2: MOTOR_PWM) and sends STOP; :meth:`Rplidar.poll` then
walks the start-up as the SDK does, one request at a time with a retry: GET_INFO, GET_HEALTH, SCAN.  Nodes are
gathered into full revolutions (:class:`Scan`, split at each start flag).

What makes the robot stop using the scanner (:attr:`Rplidar.usable` False; one log line each, naming the port):

* health ``error`` (protection stop) again after one RESET (the protocol's way out of a protection stop; the
  SDK's clients do the same): the scan is not started;
* no answer to a start-up request after :data:`REQUEST_TRIES` tries;
* a stall: scanning, and no node for ``stall_timeout`` seconds (the motor stopped, the laser failed, the cable is
  out).  The driver sends STOP and SCAN again once a second; the scanner is usable again after its next full
  revolution (and logs that);
* the port closed or failing (:data:`runtime.drivers.base.LOST_AFTER` failed reads in a row, one a poll): the port
  is closed and never read again.

Scans are in the device's terms: angle in degrees clockwise, range in metres (nodes with distance 0, "no
measurement", are left out), quality; :func:`robot_ranges` turns one into the ``(bearing, distance)`` pairs of
:class:`runtime.drivers.base.BaseSensors.ranges` for a given mount.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from runtime.config.build import rng
from runtime.drivers import rplidar_protocol as P
from runtime.drivers.base import DeviceLost
from runtime.drivers.serial_link import SerialLink
from runtime.errors import InputError
from runtime.log import get_logger

REQUEST_TIMEOUT = 0.5      # s for an answer to GET_INFO / GET_HEALTH / SCAN before asking again
REQUEST_TRIES = 4          # then the scanner is given up
RESET_WAIT = 0.05          # s after RESET before the next request (the protocol asks for at least 2 ms)
RESTART_EVERY = 1.0        # s between STOP + SCAN while stalled
MIN_SCAN_NODES = 5         # a "revolution" with fewer nodes (the one cut by a resynchronisation) is dropped


MOUNT_RANGES = {"items": (rng(-2.0, 2.0), rng(-2.0, 2.0), rng(-7.0, 7.0))}   # a sensor's pose on its robot


@dataclass(frozen=True)
class RplidarConfig:
    """A ``sensors:`` entry of ``type: rplidar``."""
    type: Literal["rplidar"] = "rplidar"
    port: str = "/dev/ttyUSB0"                    # any pyserial URL
    baudrate: int = field(default=115200, metadata=rng(9600, 1000000))   # A1 and A2M8: 115200
    model: Literal["a1", "a2"] = "a1"             # a1: motor by DTR; a2: motor by MOTOR_PWM
    motor_pwm: int = field(default=P.DEFAULT_PWM, metadata=rng(0, P.MAX_PWM))
    stall_timeout: float = field(default=0.5, metadata=rng(0.05, 10.0))  # s without a node while scanning
    # x, y (m) on the robot (within 2 m of its centre), yaw (rad, a little over a turn either way)
    mount: tuple[float, float, float] = field(default=(0.0, 0.0, 0.0), metadata=MOUNT_RANGES)
    height: float = field(default=0.25, metadata=rng(0.0, 3.0))          # m above the floor (the SITL's beams)


@dataclass(frozen=True)
class Scan:
    """One revolution: ``points`` are (angle degrees clockwise, range m, quality), in arrival order."""
    t: float                                      # the poll time at which its last node arrived
    points: tuple[tuple[float, float, int], ...]
    nodes: int                                    # nodes in the revolution, those without a measurement included


@dataclass
class RplidarStats:
    scans: int = 0
    short_scans: int = 0          # revolutions dropped for fewer than MIN_SCAN_NODES nodes
    stalls: int = 0
    retries: int = 0
    link: dict = field(default_factory=dict)    # the serial link's counters (bytes_in, read_errors, ...)


def robot_ranges(scan: Scan, mount: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> tuple[tuple[float, float], ...]:
    """``(bearing rad counter-clockwise, distance m)`` from the robot's centre of each point of ``scan`` for a
    scanner at ``mount`` = (x, y, yaw) on the robot (its forward mark along ``yaw``)."""
    mx, my, myaw = mount
    out = []
    for angle, r, _q in scan.points:
        a = myaw - math.radians(angle)
        px, py = mx + r * math.cos(a), my + r * math.sin(a)
        out.append((math.atan2(py, px), math.hypot(px, py)))
    return tuple(out)


class Rplidar:
    """One scanner on one port; call :meth:`poll` with the time every cycle."""

    Config = RplidarConfig
    kind = "laser"             # what the robot can offer (an allocation's sensor view)
    reports = "ranges"         # the daemon merges ranges() into BaseSensors.ranges

    @classmethod
    def from_config(cls, cfg: RplidarConfig, robot_id=None) -> "Rplidar":
        return cls(cfg.port, baudrate=cfg.baudrate, model=cfg.model, motor_pwm=cfg.motor_pwm,
                   stall_timeout=cfg.stall_timeout, mount=tuple(cfg.mount), robot_id=robot_id)

    def __init__(self, port: str, baudrate: int = 115200, model: str = "a1", motor_pwm: int = P.DEFAULT_PWM,
                 stall_timeout: float = 0.5, mount: tuple[float, float, float] = (0.0, 0.0, 0.0), robot_id=None):
        if model not in ("a1", "a2"):
            raise InputError(f"rplidar model: expected a1 or a2, got {model!r}")
        self.port, self.baudrate, self.model = port, baudrate, model
        self.motor_pwm = int(motor_pwm)
        self.stall_timeout = float(stall_timeout)
        self.mount = tuple(float(v) for v in mount)
        self.log = get_logger("rplidar", robot_id)
        self.parser = P.ResponseParser()
        self.stats = RplidarStats()
        self.info: P.DeviceInfo | None = None
        self.health: P.Health | None = None
        self.latest: Scan | None = None
        self.state = "closed"          # closed | info | health | reset | scan | scanning | failed | lost
        self.resets = 0
        self.stalled = False
        self.link = SerialLink(port, baudrate, "rplidar", self.log, self.stats.link, quiet=True)
        self._sent_at = 0.0
        self._tries = 0
        self._last_node: float | None = None
        self._nodes: list[P.Node] = []

    # ------------------------------------------------------------------ state
    @property
    def usable(self) -> bool:
        """Scanning, not stalled, and a full revolution has arrived since it (re)started."""
        return self.state == "scanning" and not self.stalled and self.latest is not None

    def ranges(self) -> tuple[tuple[float, float], ...]:
        """The latest revolution as ``BaseSensors.ranges`` pairs (:func:`robot_ranges` at the mount); none while the
        scanner is not usable, so a robot stops using a stalled, failed or lost scanner."""
        return robot_ranges(self.latest, self.mount) if self.usable else ()

    def open(self, now: float = 0.0) -> None:
        """Open the port (InputError naming it if it does not open), start the motor, STOP, then GET_INFO."""
        self.link.open()
        if self.model == "a1":
            try:
                self.link.ser.dtr = False   # MOTOCTL low: the A1's motor runs (a pty has no modem lines)
            except Exception as exc:        # SerialException, OSError (ENOTTY on a pty)
                self.log.debug("rplidar on %s: no DTR line (%s)", self.port, exc)
        self._write(P.request(P.CMD_STOP))
        if self.model == "a2":
            self._write(P.motor_pwm(self.motor_pwm))
        self.parser.reset()
        self._ask("info", P.CMD_GET_INFO, now)

    def close(self) -> None:
        """STOP (and the A2's motor off) and close; never raises."""
        if self.link.ser is None:
            return
        if self.state != "lost":
            self._write(P.request(P.CMD_STOP))
            if self.model == "a2":
                self._write(P.motor_pwm(0))
        self.link.close()
        if self.state != "lost":
            self.state = "closed"

    # ------------------------------------------------------------------ polling
    def poll(self, now: float) -> list[Scan]:
        """Read what has arrived and return the revolutions it completed; never raises."""
        if self.link.ser is None or self.state in ("lost", "closed"):
            return []
        failed = self.stats.link.get("read_errors", 0)
        try:
            data = self.link.read_all()
        except DeviceLost as exc:
            self.log.warning("rplidar on %s: port lost (%s): not used", self.port, exc)
            self.state = "lost"
            self.link.close()
            return []
        if self.stats.link["read_errors"] > failed:
            return []             # a failing port: lost after LOST_AFTER of these, not a stalled scanner
        scans: list[Scan] = []
        for item in self.parser.feed(data):
            if isinstance(item, P.Node):
                self._node(item, now, scans)
            elif isinstance(item, P.DeviceInfo) and self.state == "info":
                self.info = item
                self.log.info("rplidar on %s: %s, firmware %d.%02d, hardware %d", self.port, item.name,
                              item.firmware[0], item.firmware[1], item.hardware)
                self._ask("health", P.CMD_GET_HEALTH, now)
            elif isinstance(item, P.Health) and self.state == "health":
                self.health = item
                if item.status == P.HEALTH_ERROR and self.resets == 0:
                    self.log.debug("rplidar on %s: health error (code %d): RESET", self.port, item.error_code)
                    self.resets += 1
                    self.state, self._sent_at = "reset", now
                    self._write(P.request(P.CMD_RESET))
                    continue
                if item.status == P.HEALTH_ERROR:
                    self.state = "failed"
                    self.log.warning("rplidar on %s: health error (code %d) after a reset: not used", self.port,
                                     item.error_code)
                    return scans
                if item.status == P.HEALTH_WARNING:
                    self.log.warning("rplidar on %s: health warning (code %d)", self.port, item.error_code)
                self._ask("scan", P.CMD_SCAN, now)
        if self.state == "scan" and self.parser.streaming:
            self.state = "scanning"
            self._last_node = now
        self._timers(now)
        return scans

    def _node(self, node: P.Node, now: float, scans: list[Scan]) -> None:
        if self.state == "scan":
            self.state = "scanning"
        self._last_node = now
        if node.start and self._nodes:
            if len(self._nodes) >= MIN_SCAN_NODES:
                pts = tuple((n.angle, n.distance / 1000.0, n.quality) for n in self._nodes if n.distance_q2)
                scan = Scan(now, pts, len(self._nodes))
                scans.append(scan)
                self.latest = scan
                self.stats.scans += 1
                if self.stalled:
                    self.stalled = False
                    self.log.warning("rplidar on %s: scanning again", self.port)
            else:
                self.stats.short_scans += 1
            self._nodes = []
        if node.start or self._nodes:
            self._nodes.append(node)

    def _timers(self, now: float) -> None:
        if self.state == "reset" and now - self._sent_at >= RESET_WAIT:
            self.parser.reset()                      # whatever the core said while rebooting
            self._ask("health", P.CMD_GET_HEALTH, now)
            return
        if self.state in ("info", "health", "scan") and now - self._sent_at >= REQUEST_TIMEOUT:
            if self._tries >= REQUEST_TRIES:
                self.log.warning("rplidar on %s: no answer to %s after %d tries: not used", self.port,
                                 self.state.upper() if self.state != "info" else "GET_INFO", self._tries)
                self.state = "failed"
                return
            self.stats.retries += 1
            self._ask(self.state, {"info": P.CMD_GET_INFO, "health": P.CMD_GET_HEALTH, "scan": P.CMD_SCAN}[self.state],
                      now, retry=True)
        elif self.state == "scanning" and self._last_node is not None and now - self._last_node > self.stall_timeout:
            if not self.stalled:
                self.stalled = True
                self.stats.stalls += 1
                self.log.warning("rplidar on %s: no measurement for %.2f s: not used until it scans again",
                                 self.port, now - self._last_node)
            if now - self._sent_at >= RESTART_EVERY:
                self._nodes = []
                self._write(P.request(P.CMD_STOP))
                self.parser.reset()
                self._write(P.request(P.CMD_SCAN))
                self._sent_at = now

    def _ask(self, state: str, cmd: int, now: float, retry: bool = False) -> None:
        if retry and state != "info":
            self._write(P.request(P.CMD_STOP))       # a scan that did start must not bury the next answer
            self.parser.reset()
        self._tries = self._tries + 1 if retry else 1
        self.state = state
        self._sent_at = now
        self._write(P.request(cmd))

    def _write(self, data: bytes) -> bool:
        return self.link.write(data)
