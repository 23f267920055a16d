"""runtime.execution.detour: a robot held in front of an obstacle by a pull and a push takes a detour."""
from __future__ import annotations

import logging
import math

import numpy as np

from runtime.execution import detour as D

LOG = logging.getLogger("test.detour")
NONE = np.zeros((0, 3))


def _run(detour, poses, target, obstacles=NONE, dt=0.1, start=0.0):
    """(time, goal) for each pose in turn, one control cycle apart."""
    return [(start + i * dt, detour.goal(p, target, start + i * dt, lambda: obstacles)) for i, p in enumerate(poses)]


def test_a_robot_that_gets_no_nearer_heads_for_a_point_on_the_roomier_side_then_for_its_target_again():
    d = D.Detour(LOG, "test")
    target = (5.0, 0.0)
    wall_to_the_left = np.array([[0.3, 1.0, 0.3]])
    steps = int(D.STUCK_TIME / 0.1) + 2
    out = _run(d, [(0.0, 0.0, 0.0)] * steps, target, wall_to_the_left)
    assert all(g == target for t, g in out if t <= D.STUCK_TIME)
    t0, point = out[-1]
    assert d.count == 1 and point != target
    a = math.radians(-75.0)                                         # right of the bearing: away from the wall
    assert np.allclose(point, (D.DETOUR_REACH * math.cos(a), D.DETOUR_REACH * math.sin(a)))
    # on the detour until DETOUR_TIME has passed (still stuck where it was), then the target again
    later = _run(d, [(0.0, 0.0, 0.0)] * 3, target, wall_to_the_left, start=t0 + D.DETOUR_TIME - 0.1)
    assert later[0][1] == point and later[-1][1] == target
    # or until it reaches the point
    d2 = D.Detour(LOG, "test")
    t1, p2 = _run(d2, [(0.0, 0.0, 0.0)] * steps, target)[-1]
    assert d2.goal((p2[0], p2[1] + 0.1, 0.0), target, t1 + 1.0, lambda: NONE) == target


def test_a_robot_that_keeps_getting_nearer_never_detours():
    d = D.Detour(LOG, "test")
    poses = [(0.02 * i, 0.0, 0.0) for i in range(200)]             # 0.2 m/s: 0.8 m per STUCK_TIME
    assert all(g == (5.0, 0.0) for _, g in _run(d, poses, (5.0, 0.0)))
    assert d.count == 0


def test_being_held_still_or_a_new_target_restarts_the_count():
    d = D.Detour(LOG, "test")
    here = (0.0, 0.0, 0.0)
    _run(d, [here] * 30, (5.0, 0.0))                               # 3 s stuck
    d.held(3.0)                                                     # then held still by something else
    assert all(g == (5.0, 0.0) for _, g in _run(d, [here] * 35, (5.0, 0.0), start=3.1))
    assert all(g == (0.0, 5.0) for _, g in _run(d, [here] * 35, (0.0, 5.0), start=6.6))
    assert d.count == 0
