"""A new allocation method is one package plus one registry line (docs/architecture.md#an-allocation-method).

tests/toy_method/ is such a package; this test adds its line to ``METHODS`` and nothing else, then: a robot
config names it (``allocation.method: toy``), its message joins the fleet's MAVLink dialect and codec, and two
robot cores share two tasks with it.
"""
from __future__ import annotations

import math

import pytest

from runtime import config as C
from runtime.allocation import registry
from runtime.comms import codec, dialect
from runtime.drivers.base import BaseSensors
from runtime.robot.core import Inbox, RobotCore, Sensed
from runtime.robot.ports import BaseFacts
from runtime.tasks import kind
from runtime.tasks.goto import Goto
from tests.codec_util import codec_registry_kept


@pytest.fixture
def toy(monkeypatch, tmp_path):
    # the codec's registry is kept first, so what it keeps is the fleet without the toy (kept after the line below, a
    # process's first registration took the toy in and left it there for the tests after: ToyClaim with no message
    # in the fleet's dialect)
    with codec_registry_kept():                                             # the rest of the suite never sees it
        monkeypatch.setitem(registry.METHODS, "toy", "tests.toy_method:TOY")     # the one line
        monkeypatch.setenv("MRTA_CACHE_DIR", str(tmp_path / "cache"))           # a dialect that includes toy.xml
        monkeypatch.setattr(dialect, "_loaded", {})
        monkeypatch.setattr(dialect, "_by_file", {})
        monkeypatch.setattr(codec, "_fleet_registered", False)             # registered as in a new process
        yield registry.method("toy")


def _cfg(rid: int, peers) -> C.RobotConfig:
    return C.from_dict(C.RobotConfig, {
        "robot": {"id": rid}, "gps": {"enabled": False}, "planning": {"planner": "euclid"},
        "comms": {"peers": [{"id": p, "address": f"127.0.0.1:{14600 + p}"} for p in peers]},
        "allocation": {"method": "toy"},
    }, "robot.yaml")


def test_a_config_names_the_new_method_and_a_wrong_name_lists_it(toy):
    assert type(_cfg(1, ()).allocation).__name__ == "ToyOptions"
    with pytest.raises(C.ConfigError, match="toy"):
        C.from_dict(C.RobotConfig, {"allocation": {"method": "nonesuch"}}, "robot.yaml")


def test_its_message_travels_in_the_fleet_dialect(toy):
    from tests.toy_method.messages import ToyClaim
    module = dialect.load()
    assert hasattr(module, "MAVLINK_MSG_ID_MRTA_TOY_CLAIM")
    mav = module.MAVLink(None, srcSystem=3, srcComponent=1)
    claim = ToyClaim(3, 0, (1 << 16) | 2, 1.5)
    wire = codec.to_mavlink(claim, module)
    back = codec.from_mavlink(mav.parse_char(wire.pack(mav)))
    assert back == claim
    with pytest.raises(codec.InvalidMessage):
        codec.from_mavlink(mav.parse_char(codec.to_mavlink(ToyClaim(3, 0, 7, 1.0), module).pack(mav)))


def test_two_cores_share_two_tasks_with_it(toy):
    ids = (1, 2)
    cores = {r: RobotCore(_cfg(r, [p for p in ids if p != r]), BaseFacts(radius=0.17)) for r in ids}
    poses = {1: [0.0, 0.0, 0.0], 2: [0.0, 3.0, 0.0]}
    mail: dict[int, list] = {r: [] for r in ids}

    def post(sender, msgs):
        for r in ids:
            if r != sender:
                mail[r] += msgs

    items = []
    for x, y in ((2.0, 0.2), (2.0, 2.8)):
        command, params = kind("goto").to_item(Goto(x, y))
        items.append((command, 4, params, x, y))
    post(1, cores[1].port.hand_in(items, 0.0))
    done: dict[int, int] = {}
    now = 0.0
    for _ in range(600):                       # 30 s at 20 Hz, poses moved by each core's command
        now += 0.05
        for r in ids:
            inbox, mail[r] = mail[r], []
            out = cores[r].step(now, Sensed(pose=tuple(poses[r]), sensors=BaseSensors()), Inbox(peers=inbox))
            post(r, out.peer_messages())
            v, w = out.command
            p = poses[r]
            p[2] += w * 0.05
            p[0] += v * math.cos(p[2]) * 0.05
            p[1] += v * math.sin(p[2]) * 0.05
            for ev in cores[r].node.events:
                if ev.what == "done":
                    done[ev.task] = r
        if len(done) == 2:
            break
    assert sorted(done.values()) == [1, 2]                     # each robot did one: the nearer one
    assert math.hypot(poses[1][0] - 2.0, poses[1][1] - 0.2) < 0.2
    assert math.hypot(poses[2][0] - 2.0, poses[2][1] - 2.8) < 0.2
