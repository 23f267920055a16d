"""Helpers every differential-drive body shares: wheel command checks, contacts, yaw from a quaternion."""
from __future__ import annotations

import math

import numpy as np
import pybullet as p

from runtime.errors import InputError


def clip_wheels(robot_id: int, left_mps: float, right_mps: float, limit: float) -> tuple[float, float]:
    """(left, right) wheel speeds clipped to +-``limit`` m/s; a nan or inf is an InputError naming the robot."""
    for name, v in (("left", left_mps), ("right", right_mps)):
        if not math.isfinite(v):
            raise InputError(f"robot {robot_id}: {name} wheel speed: expected a finite number, got {v!r}")
    return max(-limit, min(limit, float(left_mps))), max(-limit, min(limit, float(right_mps)))


def touching(client: int, body_id: int, margin: float) -> list:
    """Contact points of ``body_id`` with other bodies, closer than ``margin``, as pybullet reports them."""
    return [cp for cp in p.getContactPoints(bodyA=body_id, physicsClientId=client)
            if cp[2] != body_id and cp[8] <= margin]


def yaw_of(orn) -> float:
    """Heading (rad) of a quaternion (x, y, z, w)."""
    qx, qy, qz, qw = orn
    return math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


def tyre_radii(rng, nominal: float, sigma: float) -> tuple[float, float]:
    """(left, right) rolling radii: tyre tolerance and wear put each off ``nominal`` by ``sigma`` (relative,
    1 sigma, clipped at 3 sigma); 0 gives ideal wheels."""
    if sigma <= 0:
        return nominal, nominal
    scale = np.clip(rng.normal(1.0, sigma, size=2), 1 - 3 * sigma, 1 + 3 * sigma)
    return nominal * float(scale[0]), nominal * float(scale[1])
