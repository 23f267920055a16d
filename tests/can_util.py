"""Helpers for the CAN base tests: a kinematic two-wheel body, and a rig of the CiA 402 driver against the
emulated drives on python-can ``virtual``, through the socketcand hub, or on SocketCAN ``vcan0``."""
from __future__ import annotations

import dataclasses
import itertools
import math
import os

import can
import pytest

from runtime.drivers.cia402 import Cia402Base, Cia402Config
from sitl.devices.cia402 import Cia402Device

HAVE_VCAN = os.path.exists("/sys/class/net/vcan0")
TRANSPORTS = ["virtual", "socketcand",
              pytest.param("socketcan", marks=pytest.mark.skipif(not HAVE_VCAN, reason="no vcan0 interface here "
                                                                  "(needs the vcan kernel module)"))]
DEVICE_PERIOD = 0.005
_channels = itertools.count()


class WheelBody:
    """Kinematic differential drive: the wheels turn at their targets at once; ground-truth pose integrated
    from the wheels with ``radius`` and ``track``."""

    def __init__(self, radius: float = 0.075, track: float = 0.34):
        self.radius, self.track = radius, track
        self.rates = [0.0, 0.0]
        self.angles = [0.0, 0.0]
        self.x = self.y = self.theta = 0.0

    def set_wheel_rates(self, left, right):
        self.rates = [float(left), float(right)]

    def wheel_angles(self):
        return tuple(self.angles)

    def wheel_rates(self):
        return tuple(self.rates)

    def step(self, dt):
        dl, dr = (r * dt * self.radius for r in self.rates)
        self.angles = [a + r * dt for a, r in zip(self.angles, self.rates)]
        ds, dth = (dl + dr) / 2, (dr - dl) / self.track
        self.x += ds * math.cos(self.theta + dth / 2)
        self.y += ds * math.sin(self.theta + dth / 2)
        self.theta += dth


class Rig:
    """The driver and the two emulated drives on one transport, stepped in sim time: ``step`` runs the device
    every 5 ms and the driver (poll, then a command) every control period."""

    def __init__(self, transport: str = "virtual", period: float = 0.05, **cfg):
        self.body = WheelBody()
        self.cfg = Cia402Config(**cfg)
        if transport == "socketcand":
            self.dev = Cia402Device(self.body, self.cfg, robot_id=1)
            self.driver_cfg = dataclasses.replace(self.cfg, **self.dev.endpoint())
        else:
            bus = {"interface": "virtual", "channel": f"cia402-test-{os.getpid()}-{next(_channels)}"} \
                if transport == "virtual" else {"interface": "socketcan", "channel": "vcan0"}
            self.dev = Cia402Device(self.body, self.cfg, robot_id=1, bus=bus)
            self.driver_cfg = dataclasses.replace(self.cfg, **bus)
        self.base = Cia402Base(self.driver_cfg, 1)
        self.period = period
        self.t = 0.0
        self.v = self.w = 0.0
        self.polling = True              # False: the daemon is dead (no polls, no heartbeats, no commands)

    @property
    def left(self):
        return self.dev.drives["left"]

    @property
    def right(self):
        return self.dev.drives["right"]

    def open(self):
        self.base.open(self.t)
        return self

    def step(self, seconds: float, until=None) -> float | None:
        """Run ``seconds`` of sim time; with ``until(rig)``, stop at the first control cycle where it holds and
        return that time."""
        end = self.t + seconds - 1e-9
        while self.t < end:
            n = round(self.period / DEVICE_PERIOD)
            for _ in range(n):
                self.body.step(DEVICE_PERIOD)
                self.t += DEVICE_PERIOD
                self.dev.service(self.t)
            if self.polling:
                self.base.poll(self.t)
                self.base.set_velocity(self.v, self.w, self.t)
            if until is not None and until(self):
                return self.t
        return None

    def close(self):
        try:
            if self.base.is_open:
                self.base.close()
        finally:
            self.dev.close()


class Sniffer:
    """Every frame on a ``virtual`` channel, as a bus analyser sees it."""

    def __init__(self, channel: str):
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.frames: list[tuple[int, bytes]] = []

    def take(self) -> list[tuple[int, bytes]]:
        while (m := self.bus.recv(0)) is not None:
            self.frames.append((m.arbitration_id, bytes(m.data)))
        return self.frames

    def close(self):
        self.bus.shutdown()
