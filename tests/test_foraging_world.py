"""The foraging world: discs collide and push, never overlap; the closed-form sonar ring sees robots and walls
at the right range and bearing (checked against pybullet ray casts in the same world); bumpers; removal;
bit-for-bit repeatable."""
from __future__ import annotations

import math

import numpy as np
import pybullet as p
import pytest

from runtime.drivers.arcos_protocol import P3DX_SH
from runtime.errors import InputError
from sitl.sensing import sonar_ring as sonar
from sitl.foraging.world import RADIUS, ROT_ACC, ForagingWorld


def drive(world, commands: dict, seconds: float, period: float = 0.1, track=None):
    for _ in range(int(round(seconds / period))):
        for rid, (v, w) in commands.items():
            world.command(rid, v, w)
        world.advance(period)
        if track is not None:
            track.append(world.poses.copy())


def test_a_robot_drives_at_its_command_after_the_ramp():
    with ForagingWorld({1: (-3.0, 0.0, 0.0)}) as w:
        drive(w, {1: (0.25, 0.0)}, 10.0)
        x, y, yaw = w.pose(1)
        # 0.25 m/s after a 0.83 s ramp at 0.3 m/s^2: 2.5 m less 0.10 m
        assert x + 3.0 == pytest.approx(2.5 - 0.25 ** 2 / (2 * 0.3), abs=0.03) and abs(y) < 1e-6
        yaw0 = w.pose(1)[2]
        drive(w, {1: (0.0, 1.0)}, math.pi)                  # pi s at 1 rad/s, less the ramp from standing
        assert w.pose(1)[2] - yaw0 == pytest.approx(math.pi - 1.0 / (2 * ROT_ACC), abs=0.05)


def test_robots_driving_into_each_other_never_overlap():
    track = []
    with ForagingWorld({1: (-1.0, 0.0, 0.0), 2: (1.0, 0.05, math.pi)}) as w:
        drive(w, {1: (0.25, 0.0), 2: (0.25, 0.0)}, 15.0, track=track)
    gaps = [math.dist(t[0, :2], t[1, :2]) - 2 * RADIUS for t in track]
    assert min(gaps) > -0.01                                   # contact, at most 1 cm of solver overlap
    assert min(gaps) < 0.01                                    # they did meet


def test_a_driving_robot_pushes_a_standing_one_slowly():
    track = []
    with ForagingWorld({1: (-2.0, 0.0, 0.0), 2: (-1.2, 0.0, 0.0), 3: (-3.0, 3.0, 0.0)}) as w:
        drive(w, {1: (0.25, 0.0), 2: (0.0, 0.0), 3: (0.25, 0.0)}, 12.0, track=track)
        pushed = w.pose(2)[0] + 1.2
        free = w.pose(3)[0] + 3.0
    assert pushed > 0.3                                         # moved by the other's motors through the contact
    assert pushed < 0.8 * (free - 0.3)                          # and more slowly than driving freely
    assert min(math.dist(t[0, :2], t[1, :2]) for t in track) > 2 * RADIUS - 0.01


def test_the_walls_hold_a_robot_in():
    with ForagingWorld({1: (4.0, 0.0, 0.0)}, size=10.0) as w:
        drive(w, {1: (0.25, 0.0)}, 10.0)
        assert w.pose(1)[0] == pytest.approx(5.0 - RADIUS, abs=0.01)
        assert tuple(w.bumpers()[0]) == (True, True)           # head-on: both sides of the bumper


def test_bumpers_by_side():
    starts = {1: (0.0, 0.0, 0.0), 2: (0.3, 0.4, 0.0),           # touching 1 ahead-left (bearing 53 deg)
              3: (-1.5, 0.0, 0.0), 4: (-1.5 - 0.5, 0.0, 0.0)}   # 4 touches 3 from behind: no front bumper
    starts[2] = (0.5 * math.cos(0.93), 0.5 * math.sin(0.93), 0.0)
    starts[4] = (-1.5 - 2 * RADIUS - 0.002, 0.0, 0.0)
    with ForagingWorld(starts) as w:
        b = w.bumpers()
    assert tuple(b[0]) == (True, False)          # robot 1: hit on its left
    assert tuple(b[1]) == (False, False)         # robot 2 faces away from 1 (1 is behind-right of it)
    assert tuple(b[2]) == (False, False)         # robot 3: touched from behind
    assert tuple(b[3]) == (True, True)           # robot 4: 3 is dead ahead


def test_overlapping_or_outside_starts_are_refused():
    with pytest.raises(InputError, match="robot 2 start: expected at least 0.5 m from robot 1"):
        ForagingWorld({1: (0.0, 0.0, 0.0), 2: (0.3, 0.0, 0.0)})
    with pytest.raises(InputError, match=r"robot 1 start \(4.9, 0\): expected inside the 10 m arena"):
        ForagingWorld({1: (4.9, 0.0, 0.0)})


def _reading_near(readings, bearing, distance, tol_bearing=0.25, tol_distance=0.03):
    return any(abs(math.remainder(b - bearing, math.tau)) < tol_bearing and abs(d - distance) < tol_distance
               for b, d in readings)


def test_sonar_sees_a_robot_ahead_and_to_the_left_at_its_range_and_bearing():
    with ForagingWorld({1: (0.0, 0.0, 0.0), 2: (1.5, 0.0, 0.0), 3: (0.0, 2.0, 0.0)}) as w:
        r = w.sonar()[0]
        readings = sonar.readings(r)
    front = [k for k, u in enumerate(P3DX_SH.sonar_units) if abs(u.heading) == 10]
    for k in front:                               # the two front transducers, 166 mm ahead, at +-10 degrees
        u = P3DX_SH.sonar_units[k]
        qx, qy = 1.5 - u.x / 1000, -u.y / 1000
        assert r[k] == pytest.approx(math.hypot(qx, qy) - RADIUS, abs=1e-9)      # the disc's centre is in the beam
    assert _reading_near(readings, 0.0, 1.5 - RADIUS)                          # about 1.25 m ahead
    assert _reading_near(readings, math.pi / 2, 2.0 - RADIUS, tol_bearing=0.1)  # and 1.75 m to the left
    assert not _reading_near(readings, -math.pi / 2, 2.0 - RADIUS, tol_distance=1.0)   # nothing to the right


def test_readings_of_all_robots_at_once_are_each_robots_readings_bit_for_bit():
    rng = np.random.default_rng(5)
    ranges = rng.uniform(0.1, 6.0, (12, sonar.N_SONARS))
    ranges[rng.random(ranges.shape) < 0.3] = sonar.MAX_RANGE
    ranges[3] = sonar.MAX_RANGE                                    # no echo at all
    assert sonar.readings_all(ranges) == [sonar.readings(r) for r in ranges]


def test_sonar_sees_a_wall_and_nothing_beyond_its_range():
    with ForagingWorld({1: (3.0, 0.0, 0.0)}, size=10.0) as w:
        r = w.sonar()[0]
    front = [k for k, u in enumerate(P3DX_SH.sonar_units) if abs(u.heading) == 10]
    for k in front:                     # the wall's normal is inside both front beams: the perpendicular distance
        assert r[k] == pytest.approx(5.0 - 3.0 - P3DX_SH.sonar_units[k].x / 1000, abs=1e-9)
    back = [k for k, u in enumerate(P3DX_SH.sonar_units) if abs(u.heading) == 170]
    assert all(r[k] == sonar.MAX_RANGE for k in back)     # the far wall is 8 m behind: no echo


def test_sonar_is_blind_nearer_than_its_minimum_range():
    # robot 2 just ahead: 0.10 m from the front transducers, inside their ring-down
    with ForagingWorld({1: (0.0, 0.0, 0.0), 2: (0.166 + 0.10 + RADIUS, 0.0, 0.0)}) as w:
        r = w.sonar()[0]
    front = [k for k, u in enumerate(P3DX_SH.sonar_units) if abs(u.heading) == 10]
    assert all(r[k] == sonar.MAX_RANGE for k in front)


def test_closed_form_sonar_equals_a_fan_of_pybullet_rays():
    """Oracle: 201 pybullet ray casts across each transducer's beam in the same world, nearest hit outside the
    minimum range; the closed form agrees within the fan's resolution."""
    rng = np.random.default_rng(3)
    starts = {1: (0.0, 0.0, 0.3), 2: (1.0, 0.6, 0.0), 3: (-0.8, 1.2, 1.0), 4: (0.2, -1.4, 2.0), 5: (3.6, 3.5, 0.0)}
    with ForagingWorld(starts, size=8.0) as w:
        for trial in range(3):
            w.poses[:, 2] = rng.uniform(-math.pi, math.pi, len(starts))
            w._sonar_at = None
            ranges = w.sonar()
            ox, oy, h = sonar.transducers(w.poses)
            for k in range(len(starts)):
                own = w.bodies[k]
                for s in range(sonar.N_SONARS):
                    ang = h[k, s] + np.linspace(-sonar.BEAM / 2, sonar.BEAM / 2, 201)
                    frm = [(ox[k, s], oy[k, s], RADIUS)] * len(ang)
                    to = [(ox[k, s] + 6 * math.cos(a), oy[k, s] + 6 * math.sin(a), RADIUS) for a in ang]
                    hits = p.rayTestBatch(frm, to, physicsClientId=w._client)
                    d = [6 * hh[2] for hh in hits if hh[0] >= 0 and hh[0] != own]
                    nearest = min(d, default=math.inf)
                    expect = sonar.MAX_RANGE if not sonar.MIN_RANGE <= nearest <= sonar.MAX_RANGE else nearest
                    assert ranges[k, s] == pytest.approx(expect, abs=0.01), (trial, k, s)


def test_a_removed_robot_is_gone_for_bodies_and_sonar():
    with ForagingWorld({1: (0.0, 0.0, 0.0), 2: (1.0, 0.0, 0.0)}) as w:
        assert w.sonar()[0, 3] < 1.0
        w.remove(2)
        assert w.sonar()[0, 3] == pytest.approx(5.0 - 0.166)          # the wall behind where robot 2 stood
        assert np.all(w.sonar()[1] == sonar.MAX_RANGE)
        drive(w, {1: (0.25, 0.0)}, 8.0)
        assert w.pose(1)[0] > 1.5                        # drove through where robot 2 stood


def test_the_same_commands_give_the_same_world_bit_for_bit():
    def run():
        starts = {1: (-1.0, 0.0, 0.0), 2: (1.0, 0.1, math.pi), 3: (0.0, -1.0, 1.5)}
        track = []
        with ForagingWorld(starts) as w:
            drive(w, {1: (0.25, 0.3), 2: (0.25, -0.2), 3: (0.2, 0.0)}, 20.0, track=track)
        return np.array(track)
    a, b = run(), run()
    assert np.array_equal(a, b)
