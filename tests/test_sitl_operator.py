"""An operator and a stock ground station against SITL robots: missions uploaded with pymavlink's own mission
handshake, bad uploads refused without touching the fleet's tasks, disarm as a stop, the connection sequence a
ground station plays, and a robot killed after it announced the tasks it received."""
from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time

import pytest

from sitl import launcher
from tests.sitl_util import ROOT, StockGcs, mavutil, shipped_fleet

MAV = mavutil.mavlink
ENU = MAV.MAV_FRAME_LOCAL_ENU
WAYPOINT = MAV.MAV_CMD_NAV_WAYPOINT


def _items(mav, system, points, command=WAYPOINT):
    """MISSION_ITEM_INT messages for (x, y) points in MAV_FRAME_LOCAL_ENU (metres * 1e4)."""
    return [mav.mission_item_int_encode(system, 1, seq, ENU, command, 0, 1, 0, 0, 0, 0,
                                        int(round(x * 1e4)), int(round(y * 1e4)), 0.0, 0)
            for seq, (x, y) in enumerate(points)]


def stock_upload(gcs: StockGcs, items, step=None, timeout=10.0, answer=None):
    """A ground station's upload as pymavlink does it by hand (MAVProxy's wp module): MISSION_COUNT, then each
    MISSION_REQUEST(_INT) answered with its item, until MISSION_ACK.  ``answer(seq) -> message or None``
    overrides what is sent for a request.  Returns the MISSION_ACK (or None on timeout)."""
    gcs.mav.mission_count_send(gcs.system, 1, len(items), 0)
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        for m in gcs.drain():
            if m.get_type() in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
                reply = items[m.seq] if answer is None else answer(m.seq)
                if reply is not None:
                    gcs.mav.send(reply)
            elif m.get_type() == "MISSION_ACK":
                return m
        step() if step is not None else time.sleep(0.002)
    return None


def _table(run):
    return {tid: e.state for tid, e in run.daemons[min(run.daemons)].node.table.entries.items()}


@pytest.mark.slow
def test_bad_uploads_are_refused_and_the_tasks_stay_as_they_were(tmp_path):
    f = launcher.build(shipped_fleet(tmp_path, "operator_4.yaml"), tmp_path / "run")
    run = launcher.Lockstep(f)
    gcs = StockGcs(f.robots[1].udp_port, 1)
    try:
        gcs.heartbeat()
        ack = stock_upload(gcs, _items(gcs.mav, 1, [(-3.0, -3.0), (3.0, 3.0)]), run.step)
        assert ack is not None and ack.type == MAV.MAV_MISSION_ACCEPTED
        for _ in range(5):
            run.step()
        before = _table(run)
        assert len(before) == 2 and all(_table(run) == before for _ in [run.step()])

        # a task off the map: the whole upload refused, a STATUSTEXT naming the item and why
        ack = stock_upload(gcs, _items(gcs.mav, 1, [(1.0, 1.0), (40.0, 0.0)]), run.step)
        assert ack is not None and ack.type == MAV.MAV_MISSION_INVALID_PARAM5_X
        texts = [m.text for m in gcs.got if m.get_type() == "STATUSTEXT"]
        assert any("item 1 refused" in t and "off the map" in t for t in texts), texts
        # inside a box is not possible in this empty arena; a command no task kind takes is refused too
        ack = stock_upload(gcs, _items(gcs.mav, 1, [(1.0, 1.0)], command=MAV.MAV_CMD_NAV_TAKEOFF), run.step)
        assert ack is not None and ack.type == MAV.MAV_MISSION_UNSUPPORTED

        # out of order: every request answered with the wrong item; the robot re-requests, then gives up
        items = _items(gcs.mav, 1, [(1.0, 1.0), (2.0, 2.0), (2.5, -1.0)])
        requests = []

        def wrong(seq):
            requests.append(seq)
            return items[(seq + 1) % 3]
        ack = stock_upload(gcs, items, run.step, timeout=60.0, answer=wrong)
        assert ack is not None and ack.type == MAV.MAV_MISSION_OPERATION_CANCELLED
        assert requests and set(requests) == {0} and len(requests) >= 5       # item 0 asked for again and again
        for _ in range(5):
            run.step()
        assert _table(run) == before and all(len(d.node.table.entries) == 2 for d in run.daemons.values())
    finally:
        gcs.close()
        run.close()
        f.close()


@pytest.mark.slow
def test_disarm_stops_the_robot_within_a_cycle_and_its_task_is_done_by_another(tmp_path):
    scenario = {"type": "mission", "tasks": [{"kind": "goto", "x": -3.5, "y": -3.5}]}
    f = launcher.build(shipped_fleet(tmp_path, "operator_4.yaml", scenario=scenario), tmp_path / "run")
    run = launcher.Lockstep(f)
    commands: dict[int, list] = {rid: [] for rid in f.robots}
    for rid, d in run.daemons.items():
        real = d.base.set_velocity
        d.base.set_velocity = lambda v, w, now, _real=real, _rid=rid: commands[_rid].append((now, v, w)) or _real(v, w, now)
    gcs = None
    try:
        holder = None
        while f.world.t < 30 and holder is None:
            run.step()
            holder = next((rid for rid, d in run.daemons.items() if d.agent.commitments and
                           math.hypot(*d._velocity()) > 0.1), None)
        assert holder is not None, "nobody took the task"
        task = run.daemons[holder].agent.commitments[0].task_id
        gcs = StockGcs(f.robots[holder].udp_port, holder)
        gcs.mav.command_long_send(holder, 1, MAV.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 0, 0, 0, 0, 0, 0)
        sent_at = f.world.t
        acks = gcs.wait(lambda m: m.get_type() == "COMMAND_ACK", 5.0, run.step)
        assert acks and acks[-1].result == MAV.MAV_RESULT_ACCEPTED
        # the first cycle after the command: zero velocity to the base (one control period)
        after = [c for c in commands[holder] if c[0] > sent_at]
        assert after[0][1:] == (0.0, 0.0), after[:3]
        assert not run.daemons[holder].agent.commitments and not run.daemons[holder].node.armed
        # someone else does the task (the operator sees it done)
        from sitl.operator import RunView
        while f.world.t < 120 and not f.scenario.goal(RunView(run.op)):
            run.step()
        res = launcher.finish(f, run.op, timed_out=False)
        assert res["goal_met"], res
        done_by = run.op.done_by[task]
        assert done_by and holder not in done_by, (holder, done_by)
        assert all(v == 0.0 and w == 0.0 for _, v, w in commands[holder][len(commands[holder]) - len(after):])
    finally:
        if gcs is not None:
            gcs.close()
        run.close()
        f.close()
