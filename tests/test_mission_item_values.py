"""A robot refuses mission items whose values no task can work with at once, with the MISSION_ACK error that names
the field (issue 31, point 7): a stock pymavlink ground station's frames go through the robot core (no socket), as
a legacy MISSION_ITEM (float x/y, which can carry NaN and infinities) or a MISSION_ITEM_INT."""
from __future__ import annotations

import math

import pytest
from hypothesis import given, settings, strategies as st

from runtime import config as C
from runtime.comms import dialect
from runtime.comms import mission as M
from runtime.comms.link import LinkCounters
from runtime.drivers.base import BaseSensors
from runtime.robot.core import GCS, TO, Inbox, RobotCore, Sensed
from runtime.robot.ports import BaseFacts

mod = dialect.load()
ROBOT, ENU, WAYPOINT = 1, 4, 16
SRC = ("127.0.0.1", 14550)


class Station:
    """A pymavlink ground station (system 255) talking to one robot core through encoded frames."""

    def __init__(self):
        cfg = C.from_dict(C.RobotConfig, {"robot": {"id": ROBOT}, "gps": {"enabled": False},
                                          "planning": {"planner": "euclid"}}, "robot.yaml")
        robot_mav = mod.MAVLink(None, srcSystem=ROBOT, srcComponent=1)
        self.core = RobotCore(cfg, BaseFacts(radius=0.17), mavlink=(robot_mav, mod, LinkCounters()))
        self.tx = mod.MAVLink(None, srcSystem=255, srcComponent=190)
        self.now = 0.0

    def step(self, *msgs) -> tuple[list, list[str]]:
        """One control cycle with ``msgs`` from the station: (the replies to it, the STATUSTEXT lines sent)."""
        rx = mod.MAVLink(None)
        inbox = [(rx.parse_buffer(m.pack(self.tx))[0], SRC) for m in msgs]
        out = self.core.step(self.now, Sensed(pose=(0.0, 0.0, 0.0), sensors=BaseSensors()),
                             Inbox(ground=inbox, ground_present=True))
        self.now += 0.05
        replies = [f[1] for f in out.frames if f[0] == TO]
        texts = [f[1].text for f in out.frames if f[0] == GCS and getattr(f[1], "get_type", str)() == "STATUSTEXT"]
        return replies, texts

    def upload_one(self, item_msg) -> tuple[list, list[str]]:
        (req,), _ = self.step(self.tx.mission_count_encode(ROBOT, 1, 1, 0))
        assert req.get_type() == "MISSION_REQUEST_INT" and req.seq == 0
        return self.step(item_msg)


def legacy(station, **kw):
    f = dict(param1=0.0, param2=0.0, param3=0.0, param4=0.0, x=1.0, y=1.0, z=0.0) | kw
    return station.tx.mission_item_encode(ROBOT, 1, 0, ENU, WAYPOINT, 0, 1, f["param1"], f["param2"], f["param3"],
                                          f["param4"], f["x"], f["y"], f["z"], 0)


@pytest.mark.parametrize("field, value, code", [
    ("x", math.nan, "MAV_MISSION_INVALID_PARAM5_X"), ("x", math.inf, "MAV_MISSION_INVALID_PARAM5_X"),
    ("y", math.nan, "MAV_MISSION_INVALID_PARAM6_Y"), ("y", -math.inf, "MAV_MISSION_INVALID_PARAM6_Y"),
    ("z", math.inf, "MAV_MISSION_INVALID_PARAM7"),
    ("param1", math.inf, "MAV_MISSION_INVALID_PARAM1"), ("param2", -math.inf, "MAV_MISSION_INVALID_PARAM2"),
    ("param3", math.inf, "MAV_MISSION_INVALID_PARAM3"), ("param4", math.inf, "MAV_MISSION_INVALID_PARAM4"),
])
def test_a_legacy_item_with_a_value_no_task_can_use_is_refused_at_once(field, value, code):
    s = Station()
    replies, texts = s.upload_one(legacy(s, **{field: value}))
    (ack,) = replies                                  # answered in the same cycle: no re-request, no time-out
    assert ack.get_type() == "MISSION_ACK" and ack.type == getattr(mod, code)
    assert any(f"item 0: {field} " in t and "expected a finite number" in t for t in texts), texts
    assert s.core.port.listing() == []                # the fleet's tasks stay as they were
    assert s.step()[0] == [] and s.core.ground.mission.busy is False


def test_an_int_item_with_unset_y_is_refused_naming_y():
    s = Station()
    msg = s.tx.mission_item_int_encode(ROBOT, 1, 0, ENU, WAYPOINT, 0, 1, 0, 0, 0, 0, 10000, M.INT32_MAX, 0.0, 0)
    (ack,), _ = s.upload_one(msg)
    assert ack.type == mod.MAV_MISSION_INVALID_PARAM6_Y and s.core.port.listing() == []


def test_nan_params_are_defaults_and_the_robot_reports_what_it_added():
    """NaN in param1..4 or z is the protocol's "default" (QGC sends a NaN yaw): taken, and the robot's report of the
    upload reads back as one new task."""
    s = Station()
    (ack,), texts = s.upload_one(legacy(s, param1=math.nan, param4=math.nan, z=math.nan))
    assert ack.type == mod.MAV_MISSION_ACCEPTED and len(s.core.port.listing()) == 1
    assert [M.parse_added_report(t) for t in texts if M.parse_added_report(t)] == [(1, 0)]


def test_task_kinds_refusals_name_the_param_they_name():
    assert M.param_result("param2 (value): expected a finite number >= 0, got nan") == 7
    assert M.param_result("param1 (robots needed): expected an integer 1..8, got 9") == 6
    assert M.param_result("something else") == 6
    assert M.parse_added_report(M.added_report(12, 3)) == (12, 3)
    assert M.parse_added_report(M.added_report(2, 1) + ", home item 0 skipped") == (2, 1)
    assert M.parse_added_report("mission: 1 task(s) added") is None


VALUES = st.sampled_from([0.0, 1.0, -2.5, math.nan, math.inf, -math.inf]) | st.floats(width=32)


@settings(max_examples=60, deadline=None)
@given(st.fixed_dictionaries({k: VALUES for k in ("param1", "param2", "param3", "param4", "x", "y", "z")}))
def test_any_legacy_item_values_get_an_answer_in_the_same_cycle(values):
    """Whatever floats a legacy MISSION_ITEM carries, the upload ends with one MISSION_ACK in the cycle that brought
    the item (never dropped and re-requested until the station gives up); it is taken only if x and y are finite
    and nothing is infinite, and a refusal leaves the fleet's tasks as they were."""
    s = Station()
    replies, _ = s.upload_one(legacy(s, **values))
    assert [m.get_type() for m in replies] == ["MISSION_ACK"] and not s.core.ground.mission.busy
    finite_xy = math.isfinite(values["x"]) and math.isfinite(values["y"])
    infinite = any(math.isinf(v) for k, v in values.items() if k not in ("x", "y"))
    if replies[0].type == mod.MAV_MISSION_ACCEPTED:
        assert finite_xy and not infinite and len(s.core.port.listing()) == 1
    else:
        assert s.core.port.listing() == []
        if not finite_xy or infinite:
            assert replies[0].type in (mod.MAV_MISSION_INVALID_PARAM5_X, mod.MAV_MISSION_INVALID_PARAM6_Y,
                                       mod.MAV_MISSION_INVALID_PARAM7, *range(mod.MAV_MISSION_INVALID_PARAM1,
                                                                              mod.MAV_MISSION_INVALID_PARAM4 + 1))
