"""The ``transport`` task kind (paper 000's objects) and its executor: trips of load, carry, unload, driven by a
kinematic robot through the real executive (pure pursuit and the arbiter)."""
from __future__ import annotations

import logging
import math

import pytest

from runtime import tasks as T
from runtime.drivers.base import BaseSensors
from runtime.execution.executive import ExecContext, Executive, Tunables
from runtime.execution.transport import LOADING, TO_DELIVERY, TO_OBJECT, UNLOADING, TransportExecutor
from runtime.planning.robot_planner import RobotPlanner
from runtime.tasks import Commitment, Task
from runtime.tasks.transport import DELIVERED, LOADED, MAV_CMD_WAYPOINT_USER_2, Transport, from_item, to_item


def test_mission_item_round_trip_and_kind_lookup():
    spec = Transport(1.5, -2.0, 40.0, 108.0, 75.0)
    command, params = to_item(spec)
    assert command == MAV_CMD_WAYPOINT_USER_2 and T.kind_of_command(command).KIND == "transport"
    assert from_item(command, params, 1.5, -2.0) == spec


@pytest.mark.parametrize("params, why", [
    ((0.0, 108.0, 1.0, 0.0), "param1 (weight, wu): expected a number > 0"),
    ((float("nan"), 108.0, 1.0, 0.0), "param1 (weight, wu)"),
    ((40.0, 0.0, 1.0, 0.0), "param2 (deadline, s): expected a number > 0"),
    ((40.0, float("inf"), 1.0, 0.0), "param2 (deadline, s)"),
    ((40.0, 108.0, -1.0, 0.0), "param3 (maximum utility): expected a number >= 0"),
])
def test_bad_params_are_one_line_reasons(params, why):
    with pytest.raises(ValueError, match=re_escape(why)):
        from_item(MAV_CMD_WAYPOINT_USER_2, params, 0.0, 0.0)


def re_escape(s: str) -> str:
    import re
    return re.escape(s)


def _run(executive, pose, until, t0=0.0, dt=0.1, on_progress=None):
    """Drive a unicycle at the executive's commands; return the progress reported, with the pose kept."""
    got = []
    t = t0
    while t < until:
        (v, w), progress = executive.step(tuple(pose), BaseSensors(), t)
        for p in progress:
            got.append(p)
            if on_progress:
                on_progress(p)
        pose[2] += w * dt
        pose[0] += v * dt * math.cos(pose[2])
        pose[1] += v * dt * math.sin(pose[2])
        t += dt
    return got, t


def _executive():
    ctx = ExecContext(RobotPlanner(None, "euclid", 0.25, 100, 0), Tunables(0.25, 0.5, 1.0, 0.1),
                      logging.getLogger("test"), 0.25)
    return Executive(ctx)


PARAMS = (("delivery", (0.0, 0.0)), ("load", 2.0), ("load_time", 0.12), ("reach", 0.3))


def test_trips_alternate_load_and_delivery_at_the_right_places_and_times():
    ex = _executive()
    task = Task(7, "transport", Transport(1.4, 0.0, 40.0, 108.0, 100.0))
    ex.sync((Commitment(task, role="member", params=PARAMS),), 0.0)
    pose = [0.0, 0.0, 0.0]
    where = []
    got, t = _run(ex, pose, 60.0, on_progress=lambda p: where.append(tuple(pose[:2])))
    events = [p.event for p in got]
    assert events[:4] == [LOADED, DELIVERED, LOADED, DELIVERED], events
    assert all(p.data["wu"] == 2.0 for p in got)
    for p, xy in zip(got, where):
        target = (1.4, 0.0) if p.event == LOADED else (0.0, 0.0)
        assert math.dist(xy, target) <= 0.3 + 0.05, (p.event, xy)
    # from one mark's reach to the other's and back, 2 x (1.4 - 2 x 0.3) m at <= 0.25 m/s, plus 0.48 s of dwell
    deliveries = [p.t for p in got if p.event == DELIVERED]
    assert all(b - a > 2 * 0.8 / 0.25 + 0.48 for a, b in zip(deliveries, deliveries[1:]))


def test_a_changed_coalition_keeps_the_load_on_board():
    ex = _executive()
    task = Task(7, "transport", Transport(1.4, 0.0, 40.0, 108.0, 100.0))
    c = Commitment(task, role="member", params=PARAMS)
    ex.sync((c,), 0.0)
    pose = [0.0, 0.0, 0.0]
    got, t = _run(ex, pose, 30.0)
    while ex.executors[7].phase != TO_DELIVERY:
        more, t = _run(ex, pose, t + 0.1, t0=t)
    before = ex.executors[7]
    assert before.carrying == 2.0
    ex.sync((Commitment(task, partners=(3, 4), role="member", params=PARAMS),), t)
    assert ex.executors[7] is before and before.phase == TO_DELIVERY and before.carrying == 2.0
    ex.sync((), t)
    assert not ex.executors


def test_the_robot_stands_still_while_loading():
    ex = _executive()
    task = Task(7, "transport", Transport(1.0, 0.0, 40.0, 108.0, 100.0))
    ex.sync((Commitment(task, params=(("load", 10.0), ("load_time", 1.0), ("reach", 0.3))),), 0.0)
    pose = [0.0, 0.0, 0.0]
    t = 0.0
    while ex.executors[7].phase == TO_OBJECT:
        _, t = _run(ex, pose, t + 0.1, t0=t)
    assert ex.executors[7].phase == LOADING
    (v, w), _ = ex.step(tuple(pose), BaseSensors(), t + 1.0)
    assert (v, w) == (0.0, 0.0)
    assert isinstance(ex.executors[7], TransportExecutor)


def test_keep_lane_moves_each_long_leg_right_and_keeps_the_marks():
    from runtime.execution.transport import keep_lane
    path = keep_lane([(0.0, 0.0), (2.0, 0.0)], 0.3)
    assert path[0] == (0.0, 0.0) and path[-1] == (2.0, 0.0)
    assert [p[1] for p in path[1:-1]] == [-0.3, -0.3]                  # right of +x is -y
    back = keep_lane([(2.0, 0.0), (0.0, 0.0)], 0.3)
    assert [p[1] for p in back[1:-1]] == [0.3, 0.3]                    # the way back: the other lane
    assert keep_lane([(0.0, 0.0), (0.5, 0.0)], 0.3) == [(0.0, 0.0), (0.5, 0.0)]    # too short to taper
    assert keep_lane([(0.0, 0.0), (2.0, 0.0)], 0.0) == [(0.0, 0.0), (2.0, 0.0)]


def test_a_robot_that_gets_nowhere_backs_out_and_replans():
    """Held in place (pushed back by something it cannot see) while it wants to drive: after STALL_TIME s it
    backs up for ESCAPE_TIME s, once, then drives again."""
    from runtime.execution.executive import ESCAPE_TIME, STALL_TIME
    from runtime.tasks.goto import Goto
    ctx = ExecContext(RobotPlanner(None, "euclid", 0.25, 0, 1), Tunables(0.25, 0.3, 2.0, 0.12),
                      logging.getLogger("test"), 0.25, seed=1)
    ex = Executive(ctx)
    ex.sync((Commitment(Task(1, "goto", Goto(3.0, 0.0, hold=None))),), 0.0)
    cmds = []
    t = 0.0
    while t < STALL_TIME + ESCAPE_TIME + 1.0:
        (v, w), _ = ex.step((0.0, 0.0, 0.0), BaseSensors(), t)
        cmds.append((round(t, 1), v))
        t += 0.1
    assert ex.escapes == 1
    assert all(v > 0 for t, v in cmds if t < STALL_TIME)
    assert all(v < 0 for t, v in cmds if STALL_TIME + 0.15 < t < STALL_TIME + ESCAPE_TIME - 0.15)
    assert all(v > 0 for t, v in cmds if t > STALL_TIME + ESCAPE_TIME + 0.15)


def test_an_idle_robot_makes_way_only_when_armed_and_not_boxed_in():
    ctx = ExecContext(RobotPlanner(None, "euclid", 0.25, 0, 1), Tunables(0.25, 0.3, 2.0, 0.12),
                      logging.getLogger("test"), 0.25)
    ex = Executive(ctx)
    front = BaseSensors(ranges=((0.0, 0.4),))                      # something 0.15 m off its front
    assert ex.step((0.0, 0.0, 0.0), front, 0.0)[0] == (0.0, 0.0)   # not armed: never moves
    ex.make_way = True
    v, w = ex.step((0.0, 0.0, 0.0), front, 0.1)[0]
    assert v < 0 and w == 0.0                                       # backs off
    v, w = ex.step((0.0, 0.0, 0.0), BaseSensors(ranges=((math.pi, 0.4),)), 0.2)[0]
    assert v > 0                                                    # from behind: drives off forward
    boxed = BaseSensors(ranges=((0.0, 0.4), (math.pi, 0.35)))
    assert ex.step((0.0, 0.0, 0.0), boxed, 0.3)[0] == (0.0, 0.0)
    assert ex.step((0.0, 0.0, 0.0), BaseSensors(ranges=((0.0, 2.0),)), 0.4)[0] == (0.0, 0.0)


def test_circuit_legs_turn_left_round_each_mark_and_meet_at_the_tips():
    from runtime.execution.transport import TIP_POINTS, circuit_leg
    out = circuit_leg((0.0, 0.0), (3.0, 0.0), 0.4, 0.3)
    back = circuit_leg((3.0, 0.0), (0.0, 0.0), 0.4, 0.3)
    tip_out, tip_back = out[-1 - TIP_POINTS], back[-1 - TIP_POINTS]
    assert math.dist(tip_out, (3.0, 0.0)) < 0.3 and math.dist(tip_back, (0.0, 0.0)) < 0.3     # within reach
    assert out[0] == pytest.approx(tip_back) and back[0] == pytest.approx(tip_out)   # each leaves from the other's tip
    assert out[-1] == pytest.approx(back[TIP_POINTS])          # past the tip, on to the way back's lane
    assert all(y == pytest.approx(-0.4) for x, y in out if 1.0 < x < 2.0)             # right of +x is -y ...
    assert all(y == pytest.approx(0.4) for x, y in back if 1.0 < x < 2.0)             # ... and of -x, +y
    turn = out[-1 - 2 * TIP_POINTS:]                            # round the goal: counter-clockwise (left)
    cross = [(b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0]) for a, b, c in zip(turn, turn[1:], turn[2:])]
    assert all(c > 0 for c in cross)
    assert circuit_leg((0.0, 0.0), (1.0, 0.0), 0.4, 0.3) is None          # too close for two turns
    assert circuit_leg((0.0, 0.0), (3.0, 0.0), 0.0, 0.3) is None


def test_join_drives_onto_the_leg_a_little_ahead_of_the_nearest_point():
    from runtime.execution.transport import join
    leg = [(0.0, 0.0), (1.0, 0.0), (2.0, 0.0), (3.0, 0.0)]
    path = join((1.5, 0.3, 0.0), leg, 0.2)
    assert path[0] == (1.5, 0.3) and path[1] == pytest.approx((1.7, 0.0)) and path[2:] == [(2.0, 0.0), (3.0, 0.0)]
    assert join((0.5, -0.2, 0.0), leg, 0.2, since=2)[1] == pytest.approx((2.2, 0.0))      # not before point 2
    assert join((5.0, 0.1, 0.0), leg, 0.2, upto=3) == [(5.0, 0.1), (2.0, 0.0)]            # past the part searched
    assert join((5.0, 0.1, 0.0), leg, 0.2, upto=3, past=(9.0, 9.0)) == [(5.0, 0.1), (9.0, 9.0)]


def test_a_circuit_holds_robots_by_its_length_and_the_rest_wait_beside_the_object_off_it():
    from runtime.execution.transport import circuit_capacity, hold_spot
    assert [circuit_capacity(d, 1.3, 9) for d in (0.5, 1.4, 1.8, 2.5, 4.0)] == [1, 2, 2, 3, 6]
    assert circuit_capacity(4.0, 1.3, 3) == 3 and circuit_capacity(4.0, 0.0, 3) == 3
    spots = [hold_spot((2.0, 0.0), (0.0, 0.0), k, 0.25, side) for k, side in enumerate((1, -1, 1, -1))]
    assert spots[0] == pytest.approx((1.4, -1.5)) and spots[1] == pytest.approx((1.4, 2.15))   # right of the line: -y
    assert spots[2] == pytest.approx((1.4, -2.8)) and spots[3] == pytest.approx((1.4, 3.45))  # each its own distance
    assert all(math.dist(a, b) >= 0.5 for i, a in enumerate(spots) for b in spots[i + 1:])   # bodies apart


def _executor(me, partners, position=(1.4, 0.0)):
    ctx = ExecContext(RobotPlanner(None, "euclid", 0.25, 0, 1), Tunables(0.25, 0.3, 2.0, 0.12),
                      logging.getLogger("test"), 0.25, robot_id=me)
    task = Task(7, "transport", Transport(*position, 40.0, 108.0, 100.0))
    return TransportExecutor(Commitment(task, partners, "member", PARAMS), ctx), task


def test_partners_beyond_the_circuits_capacity_wait_their_turn_and_go_when_it_comes():
    """At 1.4 m the circuit holds two: of robots 1, 3, 4, 6 the two lowest ids drive, 4 and 6 wait beside the
    object, both on the arrival lane's side (right of the line from D, where the turn round the object never
    sweeps), whichever side they come from; when robot 1 leaves the coalition, 4 goes to the object."""
    from runtime.execution.transport import hold_spot
    driving, _ = _executor(3, (1, 4, 6))
    assert not driving.waiting and driving.goal == (1.4, 0.0)
    ex, task = _executor(4, (1, 3, 6))
    assert ex.waiting
    ex.begin((0.0, 1.0, 0.0), 0.0)                                # left of the line: still waits on the right
    assert ex.goal == pytest.approx(hold_spot((1.4, 0.0), (0.0, 0.0), 0, 0.25, 1.0))
    assert ex.follow.path[-1] == pytest.approx(ex.goal)           # straight to its place, not onto the circuit
    last, _ = _executor(6, (1, 3, 4))
    last.begin((0.0, -1.0, 0.0), 0.0)                             # one further out
    assert last.goal == pytest.approx(hold_spot((1.4, 0.0), (0.0, 0.0), 1, 0.25, 1.0))
    ex.update((1.4, 0.1, 0.0), 1.0)                               # passing within reach of the object ...
    assert ex.phase == TO_OBJECT                                  # ... does not load while waiting
    ex.recommit(Commitment(task, (3, 6), "member", PARAMS), 2.0)
    ex.begin((1.4, -1.5, 0.0), 2.0)
    assert not ex.waiting and ex.follow.path[-1] != pytest.approx(hold_spot((1.4, 0.0), (0.0, 0.0), 0, 0.25, 1.0))
    alone, _ = _executor(9, ())
    assert not alone.waiting                                      # no coalition: drives
    anonymous, _ = _executor(None, (1, 2, 3))
    assert not anonymous.waiting                                  # no id to take turns by: drives


def test_a_robot_carrying_a_load_finishes_its_trip_before_it_waits():
    ex, task = _executor(2, (1,))
    ex.begin((0.0, 0.0, 0.0), 0.0)
    ex.update((1.4, 0.0, 0.0), 0.0)                               # loads
    ex.update((1.4, 0.0, 0.0), 1.0)
    assert ex.phase == TO_DELIVERY
    crowd = Commitment(task, (0, 1), "member", PARAMS)            # a lower id joins: robot 2 is third of three
    ex.recommit(crowd, 1.0)
    assert not ex.waiting and ex.goal == (0.0, 0.0)               # still carries to the delivery point
    ex.update((0.0, 0.0, 0.0), 2.0)
    ex.update((0.0, 0.0, 0.0), 3.0)                               # unloads: now it waits its turn
    assert ex.phase == TO_OBJECT and ex.waiting and ex.turn == 0


def test_a_delivery_area_unloads_at_its_edge_and_the_circuit_turns_there():
    """``delivery_reach`` 1 m: the robot unloads as soon as it is within 1 m of D, loads only within ``reach`` of the
    object, and the circuit's turn at D lies 0.85 m out while the object's stays 0.255 m short of it."""
    from runtime.execution.transport import TIP_FACTOR, TIP_POINTS, circuit_leg
    params = PARAMS + (("delivery_reach", 1.0),)
    ctx = ExecContext(RobotPlanner(None, "euclid", 0.25, 0, 1), Tunables(0.25, 0.3, 2.0, 0.12),
                      logging.getLogger("test"), 0.25, robot_id=1)
    task = Task(7, "transport", Transport(3.0, 0.0, 40.0, 108.0, 100.0))
    ex = TransportExecutor(Commitment(task, (), "member", params), ctx)
    ex.begin((0.0, 0.0, 0.0), 0.0)
    ex.update((2.0, 0.0, 0.0), 0.0)
    assert ex.phase == TO_OBJECT                                  # 1 m from the object: not within its reach
    ex.update((2.8, 0.0, 0.0), 1.0)
    assert ex.phase == LOADING
    ex.update((2.8, 0.0, 0.0), 2.0)
    assert ex.phase == TO_DELIVERY
    ex.update((1.5, 0.0, 0.0), 3.0)
    assert ex.phase == TO_DELIVERY
    ex.update((0.9, 0.3, 0.0), 4.0)                               # inside the area: unloads
    assert ex.phase == UNLOADING
    back = circuit_leg((3.0, 0.0), (0.0, 0.0), 0.4, 1.0, start_reach=0.3)
    out = circuit_leg((0.0, 0.0), (3.0, 0.0), 0.4, 0.3, start_reach=1.0)
    assert math.dist(back[-1 - TIP_POINTS], (0.0, 0.0)) == pytest.approx(TIP_FACTOR * 1.0)     # the turn at D
    assert math.dist(out[-1 - TIP_POINTS], (3.0, 0.0)) == pytest.approx(TIP_FACTOR * 0.3)      # ... at the object
    assert out[0] == pytest.approx(back[-1 - TIP_POINTS]) and back[0] == pytest.approx(out[-1 - TIP_POINTS])
    assert circuit_leg((0.0, 0.0), (1.8, 0.0), 0.4, 0.3, start_reach=1.0) is None     # no room for both turns
