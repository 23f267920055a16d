"""Test doubles for the ARCOS tests: a kinematic Pioneer body and a raw client on the emulator's pty."""
from __future__ import annotations

import os

from runtime.drivers import arcos_protocol as P


class FakePioneer:
    """Kinematic stand-in for :class:`sitl.bodies.pioneer3dx.SimPioneer3DX`: wheels follow their targets at
    once unless ``stalled``; bumper bits and sonar ranges are set by the test."""

    def __init__(self, track: float = P.P3DX_SH.track_mm / 1000.0):
        self.cmd = (0.0, 0.0)
        self.travel = [0.0, 0.0]
        self.track = track
        self.stalled = [False, False]
        self.bumpers = (0, 0)
        self.ranges: dict[int, float] = {}
        self.fired: list[int] = []

    def set_wheel_speeds(self, left, right):
        self.cmd = (left, right)

    def wheel_rates(self):
        return tuple(0.0 if s else c for c, s in zip(self.cmd, self.stalled))

    def step(self, dt):
        for k, r in enumerate(self.wheel_rates()):
            self.travel[k] += r * dt

    def wheel_travel(self):
        return tuple(self.travel)

    def bumper_segments(self):
        return self.bumpers

    def sonar_ranges(self, sonars):
        self.fired += list(sonars)
        return {n: self.ranges.get(n, 5.0) for n in sonars}


class RawClient:
    """Writes packets to and reads packets from an emulator's pty, as a client program would."""

    def __init__(self, path: str):
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        self.parser = P.PacketParser()

    def send(self, *wire: bytes) -> None:
        os.write(self.fd, b"".join(wire))

    def body(self, cid: int, arg: bytes = b"") -> None:
        self.send(P.frame(bytes([cid]) + arg))

    def got(self) -> list[bytes]:
        chunks = []
        while True:
            try:
                chunk = os.read(self.fd, 4096)
            except BlockingIOError:
                break
            if not chunk:
                break
            chunks.append(chunk)
        return self.parser.feed(b"".join(chunks))

    def close(self) -> None:
        os.close(self.fd)


def run(dev, body, t0: float, t1: float, dt: float = 0.005) -> float:
    """Step a kinematic body and serve the device from ``t0`` to ``t1``; returns ``t1``."""
    n = int(round((t1 - t0) / dt))
    for k in range(1, n + 1):
        body.step(dt)
        dev.service(t0 + k * dt)
    return t0 + n * dt


def sips(bodies: list[bytes]) -> list[P.Sip]:
    return [P.decode_sip(b) for b in bodies if b[0] in P.SIP_IDS]


def wheel_speed(left_right, track=P.P3DX_SH.track_mm / 1000.0) -> tuple[float, float]:
    """(v m/s, w rad/s) of wheel speeds."""
    left, right = left_right
    return (left + right) / 2.0, (right - left) / track

