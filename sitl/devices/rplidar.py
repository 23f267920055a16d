"""Slamtec RPLIDAR A1/A2 emulator on a pty: the scanner's side of :mod:`runtime.drivers.rplidar_protocol`.

It answers GET_INFO and GET_HEALTH with a descriptor and the response, starts the node stream on SCAN or
FORCE_SCAN, stops it on STOP and RESET, and takes an A2's MOTOR_PWM (duty 0: the motor stops and so do the nodes).
GET_INFO and GET_HEALTH that arrive during a scan are held and answered once it stops, as the protocol's request
cache does.
An A1's motor follows the host's DTR line, which a pty does not carry: the emulated A1's motor always runs.
Nodes are produced at the model's sample rate of sim time, each a pybullet ray from the scanner's mounted pose on
its body at that instant (:func:`sitl.sensing.raycast.cast_many`), in batches every :data:`BATCH_PERIOD` (16 ms,
the latency timer of an FTDI USB-serial adapter, which delivers a real scanner's bytes in such chunks),
one revolution of :attr:`Model.samples` evenly spaced steps, angle 0 along the mount's heading and growing
clockwise, the first step of each revolution with the start flag.  A hit nearer than the model's minimum or
beyond its maximum range, or none, is a node with distance 0 and quality 0, as the scanner reports "no
measurement".

Numbers (the model's, with their source):

* A1 (A1M8 datasheet, "Measurement performance"): range 0.15-12 m, scan rate 5.5 Hz typical, 1 degree angular
  resolution at 5.5 Hz, "360 samples per scan": 360 steps per revolution at 5.5 Hz (1980 nodes/s, 9900 B/s, inside
  115200 baud's 11520 B/s).  GET_INFO model 0x18 (series 1, sub-model 8, as the SDK names it A1M8); firmware 1.29
  and hardware 7 are chosen (a recent A1M8's).
* A2 (A2M8 datasheet rev 2.5: 12 m range, 10 Hz typical; A2 user guide: the standard SCAN request runs in
  "compatible mode" at 2000 samples/s): 200 steps per revolution at 10 Hz, 0.15-12 m.  Model 0x28; firmware 1.27 and
  hardware 5 chosen.
* Range noise: Gaussian, sigma 0.2 % of the distance (chosen, seeded), inside the A1 datasheet's distance
  resolution of "<1 % of the distance"; distances are then quantised to the wire's 1/4 mm.
* Quality 15 for a measurement (chosen; the stock clients keep any node with quality > 0 and distance > 0).

Faults for tests: :attr:`RplidarDevice.health` (what GET_HEALTH reports; an ``error`` status also refuses SCAN, as
the protection stop does, until a RESET clears it, unless :attr:`RplidarDevice.persistent_fault`) and
:attr:`RplidarDevice.jammed` (the motor is held: no nodes while scanning).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from runtime.drivers import rplidar_protocol as P
from runtime.log import get_logger
from sitl.sensing import raycast

LASER_Z = 0.25             # m above the floor: on top of a Pioneer (0.217 m), below the SITL walls' 0.3 m
QUALITY = 15
NOISE_REL = 0.002
BATCH_PERIOD = 0.016       # s of sim time between batches of nodes (an FTDI USB-serial adapter's latency timer)


@dataclass(frozen=True)
class Model:
    name: str
    model_id: int
    firmware: tuple[int, int]
    hardware: int
    scan_hz: float
    samples: int              # steps per revolution
    min_range: float          # m
    max_range: float          # m
    motor_by_pwm: bool        # A2: MOTOR_PWM; A1: DTR

    @property
    def rate(self) -> float:
        """Nodes per second."""
        return self.scan_hz * self.samples


MODELS = {
    "a1": Model("a1", 0x18, (1, 29), 7, 5.5, 360, 0.15, 12.0, False),
    "a2": Model("a2", 0x28, (1, 27), 5, 10.0, 200, 0.15, 12.0, True),
}


@dataclass
class RplidarDeviceStats:
    requests: int = 0
    nodes: int = 0
    revolutions: int = 0
    bytes_written: int = 0
    dropped_bytes: int = 0     # not taken by a full link (no one reading the pty)
    ignored: int = 0           # requests this emulator does not implement
    rays_cast: int = 0


class RplidarDevice:
    """One emulated scanner on ``body`` at ``mount`` = (x, y, yaw) in the body frame, height ``z``."""

    @classmethod
    def from_config(cls, body, cfg, robot_id=None) -> "RplidarDevice":
        """The device for a ``sensors:`` entry ``cfg`` (:class:`runtime.drivers.rplidar.RplidarConfig`)."""
        return cls(body, model=cfg.model, mount=tuple(cfg.mount), z=cfg.height, robot_id=robot_id,
                   seed=0 if robot_id is None else int(robot_id))

    def __init__(self, body, model: str = "a1", mount: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 z: float = LASER_Z, link=None, seed: int = 0, robot_id=None, noise_rel: float = NOISE_REL,
                 batch_period: float = BATCH_PERIOD):
        if model not in MODELS:
            raise ValueError(f"rplidar model: expected one of {', '.join(MODELS)}, got {model!r}")
        if link is None:
            from sitl.devices.pty_link import open_pty
            link = open_pty()
        self.model = MODELS[model]
        self.body, self.link, self.mount = body, link, tuple(float(v) for v in mount)
        self.z = float(z)
        self.noise_rel = float(noise_rel)
        self.batch_period = float(batch_period)
        self.rng = np.random.default_rng([seed, 0x51DA])
        serial = bytes(np.random.default_rng([seed, 0xA1]).integers(0, 256, 16, dtype=np.uint8))
        self.info = P.DeviceInfo(self.model.model_id, self.model.firmware, self.model.hardware, serial)
        self.health = P.Health(P.HEALTH_GOOD, 0)
        self.jammed = False
        self.persistent_fault = False         # a RESET does not clear a health error
        self.pwm = 0
        self.scanning = False
        self.parser = P.RequestParser()
        self.stats = RplidarDeviceStats()
        self.log = get_logger("sitl.rplidar", robot_id)
        self._origin = raycast.mounted(raycast.laser(np.zeros(1)), self.mount)
        self._t0 = 0.0
        self._sent = 0
        self._batch_at = 0.0
        self._cached: list[P.Request] = []

    @property
    def path(self) -> str:
        return self.link.path

    def endpoint(self) -> dict:
        return {"port": self.link.path, "baudrate": 115200}

    @property
    def motor_running(self) -> bool:
        return not self.jammed and (self.pwm > 0 if self.model.motor_by_pwm else True)

    # ------------------------------------------------------------------ serving
    def service(self, now: float) -> int:
        """Act on the host's requests and send the nodes due at sim time ``now``; returns bytes written."""
        out = bytearray()
        try:
            got = self.link.read()
        except OSError as exc:
            self.log.debug("rplidar link read: %s", exc)
            got = b""
        for req in self.parser.feed(got):
            out += self._request(req, now)
        if self.scanning:
            if not self.motor_running:
                self._t0, self._sent = now, 0            # the head stands still: no steps pass
            elif now - self._batch_at >= self.batch_period - 1e-9:
                due = int((now - self._t0) * self.model.rate + 1e-9)
                if due > self._sent:
                    out += self.nodes(self._sent, due)
                    self._sent = due
                    self._batch_at = now
        return self._write(bytes(out)) if out else 0

    def beams(self, steps: np.ndarray) -> raycast.Beams:
        """The rays of scan steps ``steps`` (body frame): clockwise from the mount's heading."""
        angles = self.mount[2] - steps % self.model.samples * (2 * math.pi / self.model.samples)
        return raycast.Beams(self.body, self._origin, self.z, self.model.max_range).along(angles)

    def encode(self, steps: np.ndarray, dist: np.ndarray) -> bytes:
        """Nodes for scan steps ``steps`` whose rays measured ``dist`` (m)."""
        m = self.model
        out = bytearray()
        noisy = dist * (1.0 + self.noise_rel * self.rng.standard_normal(len(dist)))
        for k, d, clean in zip(steps.tolist(), noisy.tolist(), dist.tolist()):
            step = k % m.samples
            angle_q6 = round(step * 360 * 64 / m.samples) % P.FULL_TURN_Q6
            ok = m.min_range <= clean < m.max_range
            q2 = min(round(d * 4000.0), 0xFFFF) if ok else 0
            out += P.encode_node(step == 0, QUALITY if ok else 0, angle_q6, q2)
            if step == 0:
                self.stats.revolutions += 1
        self.stats.nodes += len(steps)
        return bytes(out)

    def nodes(self, first: int, end: int) -> bytes:
        """Nodes ``first`` .. ``end - 1`` since the scan began, measured now (one batch of rays)."""
        steps = np.arange(first, end)
        (dist,), n = raycast.cast_many([self.beams(steps)])
        self.stats.rays_cast += n
        return self.encode(steps, dist)

    def _request(self, req: P.Request, now: float) -> bytes:
        self.stats.requests += 1
        cmd = req.cmd
        if cmd in (P.CMD_STOP, P.CMD_RESET):
            self.scanning = False
            if cmd == P.CMD_RESET and not self.persistent_fault:
                self.health = P.Health(P.HEALTH_GOOD, 0)     # the core reboots out of a protection stop
            cached, self._cached = self._cached, []
            return b"".join(self._request(r, now) for r in cached)
        if self.scanning and cmd in (P.CMD_GET_INFO, P.CMD_GET_HEALTH):
            self._cached.append(req)         # the protocol stack holds it until the multiple response ends
            return b""
        if cmd in (P.CMD_SCAN, P.CMD_FORCE_SCAN):
            if self.health.status == P.HEALTH_ERROR:
                return b""
            self.scanning, self._t0, self._sent, self._batch_at = True, now, 0, now
            return P.descriptor(P.NODE_LEN, P.MODE_MULTIPLE, P.TYPE_SCAN)
        if cmd == P.CMD_GET_INFO:
            return P.descriptor(P.INFO_LEN, P.MODE_SINGLE, P.TYPE_INFO) + self.info.encode()
        if cmd == P.CMD_GET_HEALTH:
            return P.descriptor(P.HEALTH_LEN, P.MODE_SINGLE, P.TYPE_HEALTH) + self.health.encode()
        if cmd == P.CMD_MOTOR_PWM and req.pwm is not None:
            if req.pwm <= P.MAX_PWM:
                self.pwm = req.pwm
            return b""
        self.stats.ignored += 1
        return b""

    def _write(self, data: bytes) -> int:
        try:
            n = self.link.write(data)
        except OSError as exc:
            self.log.debug("rplidar link write: %s", exc)
            n = 0
        n = len(data) if n is None else n
        self.stats.bytes_written += n
        self.stats.dropped_bytes += len(data) - n
        return n

    def close(self) -> None:
        self.link.close()

