"""The operator's modes as MAVSDK, MAVProxy and QGroundControl send them (ArduPilot Rover numbers), the robot's home,
telemetry rates, and mission progress that counts what the whole fleet did: through the robot core, no sockets."""
from __future__ import annotations

import math
from dataclasses import replace

import pymap3d
import pytest

from runtime.comms import dialect
from runtime.comms.link import LinkCounters
from runtime.drivers.base import BaseSensors
from runtime.messages import DONE
from runtime.robot.core import GCS, TO, Inbox, RobotCore, Sensed
from runtime.robot.ports import BaseFacts
from tests.test_robot_core import _cfg, _goto_item

mod = dialect.load()
SRC = ("127.0.0.1", 14550)
HOLD, AUTO, RTL, MANUAL = 4, 10, 11, 0
CUSTOM = mod.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED


class Rover:
    """A robot core driven like test_robot_core's (the command moves the pose, no physics), with a ground station
    that sends requests and keeps what the robot sent it."""

    def __init__(self, peers=(), start=(0.0, 0.0, 0.0)):
        self.gcs = mod.MAVLink(None, srcSystem=255, srcComponent=190)
        self.core = RobotCore(_cfg(peers=peers), BaseFacts(radius=0.17),
                              mavlink=(mod.MAVLink(None, srcSystem=1, srcComponent=1), mod, LinkCounters()))
        self.pose = list(start)
        self.now = 0.0
        self.sent: list = []            # (to whom, message): GCS (every ground station) or TO (the asker)
        self.step()

    def step(self, ground=(), peers=()) -> None:
        out = self.core.step(self.now, Sensed(pose=tuple(self.pose), sensors=BaseSensors()),
                             Inbox(ground=[(m, SRC) for m in ground], peers=list(peers), ground_present=True))
        v, w = out.command
        self.pose[2] += w * 0.05
        self.pose[0] += v * math.cos(self.pose[2]) * 0.05
        self.pose[1] += v * math.sin(self.pose[2]) * 0.05
        self.sent += [(f[0], f[1]) for f in out.frames if f[0] in (GCS, TO)]
        self.last_command = out.command
        self.now += 0.05

    def run(self, seconds: float) -> None:
        for _ in range(int(seconds / 0.05)):
            self.step()

    def command(self, cmd, *params):
        p = list(params) + [0.0] * (7 - len(params))
        self.sent.clear()
        self.step([self.gcs.command_long_encode(1, 1, cmd, 0, *p)])
        acks = [m for _, m in self.sent if _type(m) == "COMMAND_ACK" and m.command == cmd]
        assert len(acks) == 1
        return acks[0].result

    def seen(self, kind: str) -> list:
        return [m for _, m in self.sent if _type(m) == kind]

    def heartbeat(self):
        self.sent.clear()
        self.run(1.05)
        return self.seen("HEARTBEAT")[-1]


def _type(m) -> str:
    return getattr(m, "get_type", lambda: type(m).__name__)()


def test_mavsdk_hold_stops_the_robot_and_hands_its_task_back_and_start_mission_resumes():
    r = Rover()
    r.core.port.hand_in([_goto_item(3.0, 0.0)], r.now)
    r.run(1.0)
    assert r.core.agent.commitments and r.heartbeat().custom_mode == AUTO
    # MAVSDK pause_mission / Action.hold on ArduPilot: DO_SET_MODE(CUSTOM_MODE_ENABLED | SAFETY_ARMED, HOLD)
    assert r.command(mod.MAV_CMD_DO_SET_MODE, CUSTOM | mod.MAV_MODE_FLAG_SAFETY_ARMED, HOLD) == mod.MAV_RESULT_ACCEPTED
    r.step()
    assert r.last_command == (0.0, 0.0) and not r.core.agent.commitments          # stopped, task back to the fleet
    where = tuple(r.pose)
    hb = r.heartbeat()
    assert hb.custom_mode == HOLD and hb.base_mode & mod.MAV_MODE_FLAG_SAFETY_ARMED     # still armed
    assert math.dist(where[:2], r.pose[:2]) < 1e-9
    assert r.core.port.listing()[0].state != DONE
    # MAVSDK start_mission on ArduPilot: DO_SET_MODE(CUSTOM_MODE_ENABLED, AUTO)
    assert r.command(mod.MAV_CMD_DO_SET_MODE, CUSTOM, AUTO) == mod.MAV_RESULT_ACCEPTED
    r.run(1.0)
    assert r.core.agent.commitments and r.heartbeat().custom_mode == AUTO
    # the same by the generic commands: DO_PAUSE_CONTINUE 0 / MISSION_START
    assert r.command(mod.MAV_CMD_DO_PAUSE_CONTINUE, 0) == mod.MAV_RESULT_ACCEPTED and r.core.mode == "hold"
    assert r.command(mod.MAV_CMD_MISSION_START, 0, 0) == mod.MAV_RESULT_ACCEPTED and r.core.mode == "auto"


def test_return_to_launch_drives_home_and_home_position_says_where_that_is():
    start = (1.0, -1.0, 0.0)
    r = Rover(start=start)
    r.command(mod.MAV_CMD_REQUEST_MESSAGE, mod.MAVLINK_MSG_ID_HOME_POSITION)
    (home,) = r.seen("HOME_POSITION")
    d = r.core.cfg.datum
    e, n, _ = pymap3d.geodetic2enu(home.latitude / 1e7, home.longitude / 1e7, home.altitude / 1000, d.lat, d.lon,
                                   d.alt)
    assert (e, n) == (pytest.approx(1.0, abs=0.02), pytest.approx(-1.0, abs=0.02))   # where it started, not the datum
    assert (home.x, home.y) == (pytest.approx(-1.0), pytest.approx(1.0))                # NED
    r.core.port.hand_in([_goto_item(3.0, 1.0)], r.now)
    r.run(4.0)
    assert math.dist(r.pose[:2], start[:2]) > 0.5                                       # on its way
    # MAVSDK return_to_launch on ArduPilot: DO_SET_MODE(CUSTOM_MODE_ENABLED, RTL)
    assert r.command(mod.MAV_CMD_DO_SET_MODE, CUSTOM | mod.MAV_MODE_FLAG_SAFETY_ARMED, RTL) == mod.MAV_RESULT_ACCEPTED
    assert not r.core.agent.commitments                                                 # its task went back
    r.run(20.0)
    assert math.dist(r.pose[:2], start[:2]) < 0.15
    assert any(m.text == "returned to launch: at home" for m in r.seen("STATUSTEXT"))
    assert r.heartbeat().custom_mode == RTL
    assert r.command(mod.MAV_CMD_NAV_RETURN_TO_LAUNCH) == mod.MAV_RESULT_ACCEPTED       # MAV_CMD form: already


@pytest.mark.parametrize("base, custom", [(CUSTOM, MANUAL), (CUSTOM, 15), (0, AUTO), (CUSTOM, 10.5),
                                          (CUSTOM, float("nan")), (float("inf"), AUTO)])
def test_modes_the_robot_does_not_have_are_denied_with_a_reason(base, custom):
    r = Rover()
    assert r.command(mod.MAV_CMD_DO_SET_MODE, base, custom) == mod.MAV_RESULT_DENIED
    assert r.core.mode == "auto" and any("refused" in m.text for m in r.seen("STATUSTEXT"))


def test_set_mode_message_as_qgroundcontrol_sends_it():
    r = Rover()
    r.step([r.gcs.set_mode_encode(1, CUSTOM, HOLD)])
    assert r.core.mode == "hold"
    r.step([r.gcs.set_mode_encode(2, CUSTOM, AUTO)])                    # another robot's: not ours
    assert r.core.mode == "hold"


def test_message_intervals_are_set_and_read_back():
    r = Rover()
    assert r.command(mod.MAV_CMD_SET_MESSAGE_INTERVAL, mod.MAVLINK_MSG_ID_ATTITUDE, 1e6) == mod.MAV_RESULT_ACCEPTED
    assert r.command(mod.MAV_CMD_GET_MESSAGE_INTERVAL, mod.MAVLINK_MSG_ID_ATTITUDE) == mod.MAV_RESULT_ACCEPTED
    (iv,) = r.seen("MESSAGE_INTERVAL")
    assert (iv.message_id, iv.interval_us) == (mod.MAVLINK_MSG_ID_ATTITUDE, 1000000)
    r.sent.clear()
    r.run(3.0)
    assert 2 <= len(r.seen("ATTITUDE")) <= 4 and len(r.seen("GLOBAL_POSITION_INT")) >= 14
    assert r.command(mod.MAV_CMD_SET_MESSAGE_INTERVAL, mod.MAVLINK_MSG_ID_HEARTBEAT, 1e5) == \
        mod.MAV_RESULT_UNSUPPORTED
    assert r.command(mod.MAV_CMD_SET_MESSAGE_INTERVAL, mod.MAVLINK_MSG_ID_ATTITUDE, -3) == mod.MAV_RESULT_DENIED
    assert r.command(mod.MAV_CMD_SET_MESSAGE_INTERVAL, mod.MAVLINK_MSG_ID_ATTITUDE, float("nan")) == \
        mod.MAV_RESULT_DENIED
    assert r.command(mod.MAV_CMD_GET_MESSAGE_INTERVAL, float("nan")) == mod.MAV_RESULT_UNSUPPORTED
    assert r.command(mod.MAV_CMD_REQUEST_MESSAGE, mod.MAVLINK_MSG_ID_GPS_RAW_INT) == mod.MAV_RESULT_ACCEPTED
    assert r.seen("GPS_RAW_INT")[-1].fix_type == mod.GPS_FIX_TYPE_NO_GPS              # this robot has no GPS


def _mavsdk_progress(msgs, total: int) -> tuple[list[int], bool]:
    """MAVSDK mission_raw_impl.cpp: MISSION_ITEM_REACHED sets current = seq + 1 and last_reached = seq;
    MISSION_CURRENT sets current = seq unless seq == last_reached; is_mission_finished = something reached and the
    last mission_state COMPLETE.  Returns (the currents it would show, is_mission_finished)."""
    current, last_reached, state, shown = -1, -1, 0, []
    for m in msgs:
        if _type(m) == "MISSION_ITEM_REACHED":
            current, last_reached = m.seq + 1, m.seq
        elif _type(m) == "MISSION_CURRENT":
            if m.seq != last_reached:
                current = m.seq
            state = m.mission_state
        else:
            continue
        shown.append(current)
    return shown, current >= 0 and last_reached >= 0 and total > 0 and state == mod.MISSION_STATE_COMPLETE


def test_mission_progress_counts_items_done_by_any_robot():
    """MAVSDK's progress and is_mission_finished from what robot 1 sends, while robot 1 does one task and its peer
    the other (the later item first): robot 1 counts both, and never shows more done than are."""
    r = Rover(peers=(2,))
    r.core.port.hand_in([_goto_item(0.5, 0.0), _goto_item(-4.0, 0.0)], r.now)
    far = r.core.port.listing()[1]
    r.run(0.5)
    r.sent.clear()
    record = next(t for t in r.core.node.table.records(0) if t.task == far.id)
    r.step(peers=[replace(record, sender=2, state=DONE)])              # robot 2 did item 1
    assert r.seen("MISSION_ITEM_REACHED") == []                         # seq 1 + 1 = 2 would be ahead of the truth
    current = r.seen("MISSION_CURRENT")[-1]
    assert (current.seq, current.total, current.mission_state) == (1, 2, mod.MISSION_STATE_ACTIVE)
    r.run(15.0)                                                         # robot 1 does item 0
    assert [m.seq for m in r.seen("MISSION_ITEM_REACHED")] == [0, 1]    # once each, whoever did it
    current = r.seen("MISSION_CURRENT")[-1]
    assert (current.seq, current.total, current.mission_state) == (2, 2, mod.MISSION_STATE_COMPLETE)
    shown, finished = _mavsdk_progress([m for _, m in r.sent], 2)
    assert shown == sorted(shown) and set(shown) == {1, 2} and finished


def test_integer_parameters_are_int32_through_the_core():
    r = Rover()
    r.sent.clear()
    r.step([r.gcs.param_request_read_encode(1, 1, b"SYS_ARMED", -1)])
    (v,) = r.seen("PARAM_VALUE")
    assert (v.param_type, v.param_value) == (mod.MAV_PARAM_TYPE_INT32, 1.0)
