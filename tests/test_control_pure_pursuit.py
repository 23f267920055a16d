"""Pure pursuit: a kinematic unicycle follows paths and stops at the goal."""
import math

import pytest
from hypothesis import given, settings, strategies as st

from runtime.control.pure_pursuit import PurePursuit
from runtime.errors import InputError


def simulate(pp, pose, path, dt=0.05, steps=4000):
    """Integrate a unicycle; return (final pose, list of commands, max distance from the path polyline)."""
    x, y, th = pose
    cmds, worst = [], 0.0
    for _ in range(steps):
        v, w, done = pp.command((x, y, th), path)
        cmds.append((v, w, done))
        if done:
            break
        x += v * math.cos(th) * dt
        y += v * math.sin(th) * dt
        th += w * dt
        worst = max(worst, dist_to_polyline((x, y), path))
    return (x, y, th), cmds, worst


def dist_to_polyline(p, path):
    best = math.inf
    for (ax, ay), (bx, by) in zip(path, path[1:]):
        dx, dy = bx - ax, by - ay
        L2 = dx * dx + dy * dy
        t = 0.0 if L2 == 0 else max(0.0, min(1.0, ((p[0] - ax) * dx + (p[1] - ay) * dy) / L2))
        best = min(best, math.hypot(p[0] - ax - t * dx, p[1] - ay - t * dy))
    return best


def test_follows_l_shaped_path_and_stops_within_tolerance():
    pp = PurePursuit(lookahead=0.4, cruise_speed=0.3, max_turn_rate=2.0, goal_tolerance=0.05)
    path = [(0.0, 0.0), (3.0, 0.0), (3.0, 2.0)]
    (x, y, _), cmds, worst = simulate(pp, (0.0, 0.0, 0.0), path)
    assert cmds[-1][2], "never reported done"
    assert math.hypot(x - 3.0, y - 2.0) <= 0.05
    assert cmds[-1][:2] == (0.0, 0.0)
    assert worst < 0.25          # corner cut bounded by the lookahead
    assert all(0 <= v <= 0.3 + 1e-12 and abs(w) <= 2.0 + 1e-9 for v, w, _ in cmds)


def test_slows_down_near_goal():
    pp = PurePursuit(lookahead=0.4, cruise_speed=0.5, goal_tolerance=0.05)
    far = pp.command((0.0, 0.0, 0.0), [(0.0, 0.0), (5.0, 0.0)])[0]
    near = pp.command((4.7, 0.0, 0.0), [(0.0, 0.0), (5.0, 0.0)])[0]
    assert far == pytest.approx(0.5)
    assert 0 < near < far


def test_turns_in_place_when_target_behind():
    pp = PurePursuit(lookahead=0.4, cruise_speed=0.3, max_turn_rate=1.5)
    v, w, done = pp.command((0.0, 0.0, 0.0), [(0.0, 0.0), (-3.0, 0.1)])
    assert (v, done) == (0.0, False)
    assert abs(w) == 1.5


def test_large_heading_error_slows_and_steers_toward_side():
    pp = PurePursuit(lookahead=0.5, cruise_speed=0.4, max_turn_rate=10.0)
    v_straight, w_straight, _ = pp.command((0.0, 0.0, 0.0), [(0.0, 0.0), (5.0, 0.0)])
    pp.reset()
    v_side, w_side, _ = pp.command((0.0, 0.0, 0.0), [(0.0, 0.0), (0.3, 0.3), (0.3, 5.0)])
    assert w_straight == pytest.approx(0.0)
    assert w_side > 0 and v_side < v_straight


def test_curvature_is_two_y_over_l_squared():
    pp = PurePursuit(lookahead=1.0, cruise_speed=0.2, max_turn_rate=100.0, slow_radius=0.01)
    # Target point 1 m along a path starting at the robot: (0.6, 0.8) in the robot frame.
    v, w, _ = pp.command((0.0, 0.0, 0.0), [(0.0, 0.0), (0.6, 0.8), (1.2, 1.6)])
    assert w / v == pytest.approx(2 * 0.8 / 1.0)


def test_turn_rate_limit_reduces_speed_not_arc():
    pp = PurePursuit(lookahead=1.0, cruise_speed=1.0, max_turn_rate=0.5, slow_radius=0.01)
    v, w, _ = pp.command((0.0, 0.0, 0.0), [(0.0, 0.0), (0.6, 0.8), (1.2, 1.6)])
    assert w == pytest.approx(0.5)
    assert w / v == pytest.approx(1.6)


def test_progress_does_not_shortcut_a_hairpin():
    # Out along y=0 and back along y=0.3: from the start, the return leg is close but not next.
    path = [(0.0, 0.0), (3.0, 0.0), (3.0, 0.3), (0.0, 0.3)]
    pp = PurePursuit(lookahead=0.25, cruise_speed=0.3, max_turn_rate=3.0, goal_tolerance=0.05)
    (x, y, _), cmds, _ = simulate(pp, (0.5, 0.0, 0.0), path)
    assert cmds[-1][2] and math.hypot(x, y - 0.3) <= 0.05
    # It must have gone around the far end: no early "done" and enough steps for ~5.5 m.
    assert len(cmds) * 0.05 * 0.3 > 5.0


def test_drifting_near_a_later_leg_keeps_the_current_leg():
    path = [(0.0, 0.0), (3.0, 0.0), (3.0, 0.3), (0.0, 0.3)]
    pp = PurePursuit(lookahead=0.25, cruise_speed=0.3, max_turn_rate=3.0)
    pp.command((0.5, 0.0, 0.0), path)
    # Now nearer the return leg (0.1 m) than the outbound one (0.2 m): still steer forward and back down.
    v, w, done = pp.command((1.0, 0.2, 0.0), path)
    assert v > 0 and w < 0 and not done
    fresh = PurePursuit(lookahead=0.25, cruise_speed=0.3, max_turn_rate=3.0)
    assert fresh.command((1.0, 0.2, 0.0), path)[0] == 0.0     # a new follower picks the nearer leg (behind)


def test_single_waypoint_path_drives_to_it():
    pp = PurePursuit(goal_tolerance=0.05)
    (x, y, _), cmds, _ = simulate(pp, (0.0, 0.0, 1.0), [(1.0, -1.0)])
    assert cmds[-1][2] and math.hypot(x - 1.0, y + 1.0) <= 0.05


@pytest.mark.parametrize("kwargs", [dict(lookahead=0), dict(cruise_speed=-1), dict(max_turn_rate=math.nan),
                                    dict(goal_tolerance=0), dict(turn_in_place=0)])
def test_bad_parameters_raise_one_line_input_error(kwargs):
    with pytest.raises(InputError) as exc:
        PurePursuit(**kwargs)
    assert "\n" not in str(exc.value) and "pure pursuit" in str(exc.value)


def test_bad_path_and_pose_raise_input_error():
    pp = PurePursuit()
    with pytest.raises(InputError):
        pp.command((0, 0, 0), [])
    with pytest.raises(InputError):
        pp.command((0, 0, 0), [(0, 0), (math.nan, 1)])
    with pytest.raises(InputError):
        pp.command((math.inf, 0, 0), [(0, 0), (1, 1)])


coord = st.floats(-20, 20, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(pose=st.tuples(coord, coord, st.floats(-10, 10)),
       path=st.lists(st.tuples(coord, coord), min_size=1, max_size=8))
def test_commands_are_bounded_for_any_pose_and_path(pose, path):
    pp = PurePursuit(lookahead=0.4, cruise_speed=0.3, max_turn_rate=2.0, goal_tolerance=0.05)
    v, w, done = pp.command(pose, path)
    assert 0.0 <= v <= 0.3 + 1e-12 and abs(w) <= 2.0 + 1e-9
    assert done == (math.hypot(pose[0] - path[-1][0], pose[1] - path[-1][1]) <= 0.05)
    if done:
        assert (v, w) == (0.0, 0.0)
