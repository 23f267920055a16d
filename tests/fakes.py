"""Test doubles shared by the Create OI tests."""
from __future__ import annotations

import math


class FakeBody:
    """Kinematic differential drive standing in for the pybullet body: the wheels follow their targets
    at once; ground-truth pose, bumpers and wheel drops are set by the test."""

    def __init__(self, travel=(0.0, 0.0), track=0.235):
        self.cmd = (0.0, 0.0)
        self.travel = list(travel)
        self.track = track
        self.x = self.y = self.theta = 0.0
        self.bump = (False, False)
        self.drop = (False, False)
        self.calls = 0

    def set_wheel_speeds(self, left_mps, right_mps):
        self.cmd = (left_mps, right_mps)
        self.calls += 1

    def step(self, dt):
        left, right = self.cmd
        self.travel[0] += left * dt
        self.travel[1] += right * dt
        ds, dth = (left + right) / 2 * dt, (right - left) / self.track * dt
        self.x += ds * math.cos(self.theta + dth / 2)
        self.y += ds * math.sin(self.theta + dth / 2)
        self.theta += dth

    def wheel_travel(self):
        return tuple(self.travel)

    def bumps(self):
        return self.bump

    def wheel_drop(self):
        return self.drop
