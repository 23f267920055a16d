"""The robot core with no socket, device or clock: time, readings and messages in, command and frames out."""
from __future__ import annotations

import math

from runtime import config as C
from runtime.comms import dialect
from runtime.comms.link import LinkCounters
from runtime.drivers.base import BaseSensors
from runtime.robot.core import GCS, PEERS, TO, Inbox, RobotCore, Sensed
from runtime.robot.ports import BaseFacts
from runtime.tasks.goto import Goto

FRAME_LOCAL_ENU = 4


def _cfg(robot_id: int = 1, peers=(2,), method: str = "auction") -> C.RobotConfig:
    return C.from_dict(C.RobotConfig, {
        "robot": {"id": robot_id},
        "gps": {"enabled": False},
        "comms": {"peers": [{"id": p, "address": f"127.0.0.1:{14600 + p}"} for p in peers]},
        "planning": {"planner": "euclid"},
        "allocation": {"method": method},
    }, "robot.yaml")


def _goto_item(x: float, y: float):
    from runtime import tasks as T
    command, params = T.kind("goto").to_item(Goto(x, y))
    return command, FRAME_LOCAL_ENU, params, x, y


def test_a_lone_robot_takes_a_handed_in_task_and_drives_to_it():
    core = RobotCore(_cfg(peers=()), BaseFacts(radius=0.17))
    pose = [0.0, 0.0, 0.0]
    out = core.step(0.0, Sensed(pose=tuple(pose), sensors=BaseSensors()), Inbox())
    assert out.command == (0.0, 0.0)                       # nothing to do
    sent = core.port.hand_in([_goto_item(2.0, 0.0)], 0.0)  # an operator's upload, through the port
    assert sent and all(m.sender == 1 for m in sent)       # the new task record goes to the peers
    now, arrived = 0.0, []
    for _ in range(400):                                   # 20 s at 20 Hz, moved by the command, no physics
        now += 0.05
        out = core.step(now, Sensed(pose=tuple(pose), sensors=BaseSensors()), Inbox())
        v, w = out.command
        pose[2] += w * 0.05
        pose[0] += v * math.cos(pose[2]) * 0.05
        pose[1] += v * math.sin(pose[2]) * 0.05
        arrived += [p for p in out.progress if p.event == "arrived"]
        assert all(f[0] == PEERS for f in out.frames)      # no ground services: only peer messages
    assert arrived and math.hypot(pose[0] - 2.0, pose[1]) < 0.1


def test_ground_requests_come_in_as_data_and_replies_go_out_in_order():
    module = dialect.load()
    mav = module.MAVLink(None, srcSystem=250, srcComponent=190)
    core = RobotCore(_cfg(peers=()), BaseFacts(radius=0.17), mavlink=(mav, module, LinkCounters()))
    gcs = ("127.0.0.1", 14550)
    req = mav.param_request_list_encode(1, 1)
    out = core.step(0.0, Sensed(pose=(0.0, 0.0, 0.0), sensors=BaseSensors()),
                    Inbox(ground=[(req, gcs)], ground_present=True))
    kinds = [f[0] for f in out.frames]
    assert TO in kinds and GCS in kinds                     # the parameter list to the asker, telemetry to all
    assert kinds.index(TO) < kinds.index(GCS)               # replies before the cycle's reports, as sent before
    names = [getattr(f[1], "get_type", lambda m=f[1]: type(m).__name__)() for f in out.frames if f[0] == GCS]
    assert {"HEARTBEAT", "SYS_STATUS", "RobotState"} <= set(names)   # and the robot's state, a dataclass


def test_a_peer_never_heard_is_lost_after_the_start_up_grace():
    core = RobotCore(_cfg(peers=(2, 3)), BaseFacts(radius=0.17))
    grace = core.cfg.comms.startup_grace
    core.step(0.0, Sensed(pose=(0.0, 0.0, 0.0), sensors=BaseSensors()), Inbox(alive=[2]))
    core.step(grace + 0.1, Sensed(pose=(0.0, 0.0, 0.0), sensors=BaseSensors()), Inbox(alive=[2]))
    assert core.stats.peers_lost == [3]


def test_a_latched_fault_reset_is_asked_of_the_host_not_done_by_the_core():
    core = RobotCore(_cfg(peers=()), BaseFacts(radius=0.17, latches_faults=True))
    faulty = BaseSensors()
    faulty.faults = ("left_drive_fault",)
    core.step(0.0, Sensed(pose=(0.0, 0.0, 0.0), sensors=faulty), Inbox())
    assert core.port.reset_faults(0.0)
    out = core.step(0.05, Sensed(pose=(0.0, 0.0, 0.0), sensors=faulty), Inbox())
    assert out.reset_faults
    assert not core.step(0.1, Sensed(pose=(0.0, 0.0, 0.0), sensors=faulty), Inbox()).reset_faults
