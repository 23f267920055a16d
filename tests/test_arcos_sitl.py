"""Pioneer 3-DX end to end: the ArcosBase driver against the ARCOS emulator on a pybullet body, over a pty and
over TCP (odometry against ground truth, sonar seeing a box, bumpers and stall at a wall); a daemon that uses its
sonar to stay off an unmapped box; the pioneer_4 fleet reaching its formation; the emulator's watchdog stopping a
robot whose daemon was killed."""
from __future__ import annotations

import math
import os
import signal
from pathlib import Path

import pybullet as p
import pytest
import yaml

from runtime import config as C
from runtime.drivers import arcos_protocol as P
from runtime.drivers.registry import open_base
from sitl import launcher
from sitl.devices.registry import body_kind, make_device
from sitl.world import World
from tests.sitl_util import CONFIGS, shipped_fleet

PORTS = ["/dev/ttyUSB0", "socket://127.0.0.1:8101"]


def _base_cfg(**base):
    return C.from_dict(C.RobotConfig, {"base": {"type": "arcos", **base}}, "<test>").base


class Rig:
    """A world with one Pioneer, its emulator and a driver opened on the emulator's endpoint."""

    def __init__(self, port: str, start=(0.0, 0.0, 0.0), size=(8.0, 8.0)):
        self.world = World(C.WorldConfig(size=size), wheel_radius_sigma=0.0)
        cfg = _base_cfg(port=port)
        self.body = self.world.add_body(1, start, body_kind(cfg))
        self.dev = make_device(cfg, self.body, 1)
        self.drv = open_base(_base_cfg(**self.dev.endpoint()), 1)
        self.drv.open(0.0)

    def run(self, seconds: float, v: float | None = None, w: float = 0.0, until=None) -> None:
        """Step physics (5 ms) and serve the device; the driver is polled, and given (v, w), every 50 ms."""
        steps = int(round(seconds / self.world.dt))
        for k in range(steps):
            self.world.step(1)
            t = self.world.t
            self.dev.service(t)
            if k % 10 == 0:
                self.drv.poll(t)
                if v is not None and self.drv.state == "connected":
                    self.drv.set_velocity(v, w, t)
                if until is not None and until(self):
                    return

    def close(self):
        self.drv.close()
        self.dev.close()
        self.world.close()


@pytest.fixture(params=PORTS, ids=["pty", "tcp"])
def rig(request):
    r = Rig(request.param)
    yield r
    r.close()


def test_endpoint_is_the_base_config_the_launcher_writes(rig):
    ep = rig.dev.endpoint()
    assert ep["port"] == rig.dev.path and ep["baudrate"] == 9600
    if rig.dev.path.startswith("socket://"):
        assert int(ep["port"].rsplit(":", 1)[1]) >= 8101
    else:
        assert Path(ep["port"]).exists()


def test_handshake_drive_and_odometry_against_ground_truth(rig):
    rig.run(0.5)
    assert rig.drv.state == "connected" and rig.drv.identity[1:] == ("Pioneer", "p3dx-sh")
    rig.run(0.5)
    assert rig.drv.sensors.mode == "enabled"
    rig.run(4.0, v=0.3)
    rig.run(2.0, v=0.0)
    x, y, yaw = rig.body.pose()
    o = rig.drv.odometry
    assert x > 0.9
    assert math.hypot(o.x - x, o.y - y) < 0.02 * x and abs(o.theta - yaw) < 0.02
    rig.run(3.0, v=0.0, w=0.6)
    rig.run(2.0, v=0.0)
    _, _, yaw2 = rig.body.pose()
    turned = math.remainder(yaw2 - yaw, math.tau)
    assert turned > 1.0 and abs(math.remainder(rig.drv.odometry.theta - yaw2, math.tau)) < 0.03 * turned


def test_sonar_ranges_see_a_box_ahead(rig):
    rig.world.add_box((1.8, 0.0), (0.4, 1.0))               # its near face 1.6 m ahead of the axle
    rig.run(1.5)
    ahead = [(b, r) for b, r in rig.drv.sensors.ranges if abs(b) < 0.2]
    assert ahead and min(r for _, r in ahead) == pytest.approx(1.6, abs=0.05)
    behind = [r for b, r in rig.drv.sensors.ranges if abs(b) > 2.5]
    assert behind and min(behind) > 3.5                      # the arena wall 4 m behind


def test_driving_into_a_wall_sets_the_bumper_and_stall_bits():
    r = Rig(PORTS[0], start=(2.7, 0.0, 0.0))                 # the wall is 1.3 m ahead of the axle
    try:
        seen = {"bump": False, "stall": False}

        def hit(rig):
            s = rig.drv.sensors
            seen["bump"] |= s.bump_left and s.bump_right
            sip = rig.drv.last_sip
            seen["stall"] |= bool(sip and sip.stall_bumpers & (P.LEFT_STALL | P.RIGHT_STALL))
            return seen["bump"] and seen["stall"]
        r.run(12.0, v=0.3, until=hit)
        assert seen == {"bump": True, "stall": True}
        assert 4.0 - 0.17 < r.body.pose()[0] < 4.0 - 0.15     # the chassis front (0.156 m) at the wall
    finally:
        r.close()


# ----------------------------------------------------------------------------- daemons
def _one_pioneer(tmp_path: Path, sonar: bool, laser: bool = False) -> Path:
    tpl = yaml.safe_load((CONFIGS / "robots" / "pioneer3dx.yaml").read_text())
    tpl["base"]["sonar"] = sonar
    if laser:                           # an RPLIDAR A1 on top, 5 cm ahead of the centre (the launcher serves it)
        tpl["sensors"] = [{"type": "rplidar", "port": "/dev/ttyUSB2", "mount": [0.05, 0.0, 0.0]}]
    tmp_path.mkdir(parents=True, exist_ok=True)
    (tmp_path / "robot.yaml").write_text(yaml.safe_dump(tpl))
    robots = [{"id": 1, "start": [-3.0, 0.0, 0.0], "robot": str(tmp_path / "robot.yaml")}]
    scenario = {"type": "mission", "tasks": [{"kind": "goto", "x": 3.0, "y": 0.0, "hold": 1.0}]}
    return shipped_fleet(tmp_path, "pioneer_4.yaml", robots=robots, scenario=scenario)


def _drive_at_unmapped_box(tmp_path: Path, sonar: bool, laser: bool = False) -> dict:
    """One Pioneer sent 6 m straight through a 0.6 m box that is in the world but not in its map."""
    f = launcher.build(_one_pioneer(tmp_path, sonar, laser), tmp_path / "run", signing=False)
    box = f.world.add_box((0.0, 0.0), (0.6, 0.6))
    body = f.robots[1].body
    seen = {"contacts": 0, "closest_echo": math.inf, "x": -math.inf}

    def watch(fleet):
        if p.getContactPoints(bodyA=body.body_id, bodyB=box, physicsClientId=fleet.world.client_id):
            seen["contacts"] += 1
        ranges = fleet.robots[1].daemon.core.sensors.ranges        # the base's and the laser's, as the arbiter's
        if ranges:
            seen["closest_echo"] = min(seen["closest_echo"], min(r for _, r in ranges))
        seen["x"] = max(seen["x"], body.pose()[0])
    try:
        launcher.run_lockstep(f, timeout=30, on_step=watch, picture=False)
    finally:
        f.close()
    return seen


@pytest.mark.slow
def test_the_sonar_keeps_a_pioneer_off_an_unmapped_box(tmp_path):
    """With its sonar the robot never touches the box its map does not show; with the sonar off (the control)
    the same run drives into it, so it is the sonar that keeps it off."""
    with_sonar = _drive_at_unmapped_box(tmp_path / "on", sonar=True)
    assert with_sonar["contacts"] == 0 and with_sonar["closest_echo"] < 1.0 and with_sonar["x"] > -1.5
    blind = _drive_at_unmapped_box(tmp_path / "off", sonar=False)
    assert blind["contacts"] > 0 and blind["closest_echo"] == math.inf


@pytest.mark.slow
def test_a_laser_keeps_a_pioneer_with_its_sonar_off_off_an_unmapped_box(tmp_path):
    """Issue 32 point 5: the sonar off (the control above drives into the box), an RPLIDAR listed in sensors:
    instead: its ranges reach the arbiter's avoidance and the robot never touches the box."""
    laser = _drive_at_unmapped_box(tmp_path, sonar=False, laser=True)
    assert laser["contacts"] == 0 and laser["closest_echo"] < 1.0 and laser["x"] > -1.5, laser


@pytest.mark.slow
def test_pioneer_4_reaches_its_formation(tmp_path):
    f = launcher.build(shipped_fleet(tmp_path, "pioneer_4.yaml"), tmp_path / "run")
    try:
        ports = {rid: r.base_dev.path for rid, r in f.robots.items()}
        res = launcher.run_lockstep(f, timeout=120, picture=False)
    finally:
        f.close()
    assert ports[1].startswith("/dev/") and ports[2].startswith("/dev/")
    assert ports[3].startswith("socket://127.0.0.1:") and ports[4].startswith("socket://127.0.0.1:")
    assert int(ports[4].rsplit(":", 1)[1]) > int(ports[3].rsplit(":", 1)[1]) >= 8101
    assert res["goal_met"] and res["valid"], res["verdict"]
    assert all(e < 0.3 for e in res["final_error"].values()), res["final_error"]


@pytest.mark.slow
@pytest.mark.parametrize("port", PORTS, ids=["pty", "tcp"])
def test_the_emulator_stops_a_robot_2_s_after_its_daemon_is_killed(tmp_path, port):
    """Process mode: kill -9 a moving robot's daemon; on its serial port (a pty the emulator holds open, so no
    hang-up is seen) the body stops within ~2.1 s of sim time by the ARCOS watchdog; over TCP the dead process's
    socket closes, the emulator ends the session and stops the robot at once."""
    tpl = yaml.safe_load((CONFIGS / "robots" / "pioneer3dx.yaml").read_text())
    tpl["base"]["port"] = port
    (tmp_path / "robot.yaml").write_text(yaml.safe_dump(tpl))
    robots = [{"id": 1, "start": [-3.5, 0.0, 0.0], "robot": str(tmp_path / "robot.yaml")}]
    scenario = {"type": "mission", "tasks": [{"kind": "goto", "x": 3.5, "y": 0.0, "hold": 1.0}]}
    f = launcher.build(shipped_fleet(tmp_path, "pioneer_4.yaml", robots=robots, scenario=scenario),
                       tmp_path / "run", signing=False)
    body = f.robots[1].body
    state: dict = {}

    def kill_when_moving(fleet):
        t = fleet.world.t
        speed = math.hypot(*body.velocity())
        if "killed" not in state:
            if speed > 0.2:
                state["killed"] = t
                os.kill(fleet.robots[1].proc.pid, signal.SIGKILL)
            return
        if speed > 0.02:
            state["moving_until"] = t
        if t > state["killed"] + 4.0:
            raise KeyboardInterrupt                          # enough seen: end the run
    try:
        try:
            launcher.run_processes(f, 2.0, timeout=60, on_step=kill_when_moving)
        except KeyboardInterrupt:
            pass
    finally:
        f.close()
    assert "killed" in state, "the robot never moved"
    stopped_after = state.get("moving_until", state["killed"]) - state["killed"]
    dev = f.robots[1].base_dev
    if port.startswith("socket://"):
        assert stopped_after < 0.5 and dev.link.disconnects == 1 and dev.stats.watchdog_stops == 0, stopped_after
    else:
        assert 1.5 < stopped_after < 2.2 and dev.stats.watchdog_stops == 1, stopped_after
