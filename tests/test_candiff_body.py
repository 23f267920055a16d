"""The candiff body in the pybullet world, and the seam config -> body -> device -> endpoint -> driver for
``base.type: cia402`` through the socketcand hub."""
from __future__ import annotations

import math

import pytest

from runtime import config as C
from runtime.drivers import registry as drivers
from sitl.bodies import candiff
from sitl.devices import registry as devices
from sitl.world import World


@pytest.fixture
def world():
    with World(C.WorldConfig(size=(8.0, 8.0)), wheel_radius_sigma=0.0) as w:
        yield w


def run(world, body, seconds, left, right):
    body.set_wheel_rates(left, right)
    world.step(round(seconds / world.dt))


def test_straight_and_turning_follow_the_wheel_rates(world):
    body = world.add_body(1, (0.0, 0.0, 0.0), "candiff")
    world.step(40)                                              # settle on the floor
    rate = 0.5 / candiff.WHEEL_RADIUS                           # 0.5 m/s at the rim
    run(world, body, 2.0, rate, rate)
    x, y, yaw = body.pose()
    assert x == pytest.approx(0.95, abs=0.06) and abs(y) < 0.01 and abs(yaw) < 0.01
    assert body.wheel_rates()[0] == pytest.approx(rate, rel=0.02)
    assert body.wheel_angles()[0] == pytest.approx(x / candiff.WHEEL_RADIUS, rel=0.02)
    run(world, body, 1.0, -rate / 2, rate / 2)                  # in place, 0.25 m/s per wheel
    assert body.yaw_rate() == pytest.approx(0.25 / (candiff.TRACK / 2), rel=0.05)
    assert body.radius == candiff.RADIUS >= math.hypot(candiff.LENGTH, candiff.WIDTH) / 2


def test_wheel_rates_are_clipped_and_finite(world):
    body = world.add_body(1, (0.0, 0.0, 0.0), "candiff")
    body.set_wheel_rates(1e6, -1e6)
    assert body.wheel_targets() == (candiff.MAX_WHEEL_RATE, -candiff.MAX_WHEEL_RATE)
    with pytest.raises(Exception, match="finite"):
        body.set_wheel_rates(math.nan, 0.0)


def test_a_driver_opened_on_the_endpoint_drives_the_body(world):
    base_cfg = C.from_dict(C.RobotConfig, {"base": {"type": "cia402"}}, "<generated>").base
    assert devices.body_kind(base_cfg) == "candiff"
    body = world.add_body(2, (0.0, 0.0, 0.0), devices.body_kind(base_cfg))
    dev = devices.make_device(base_cfg, body, 2)
    ep = dev.endpoint()
    assert ep["interface"] == "socketcand" and ep["channel"] == "can2" and ep["host"] == "127.0.0.1"
    cfg = C.from_dict(C.RobotConfig, {"base": {"type": "cia402", **ep}}, "<generated>")
    drv = drivers.open_base(cfg.base, 2)
    try:
        drv.open(world.t)
        while world.t < 3.0:
            for _ in range(10):
                world.step(1)
                dev.service(world.t)
            drv.poll(world.t)
            drv.set_velocity(0.4, 0.0, world.t)
        x, y, _ = body.pose()
        assert x > 0.8 and abs(y) < 0.05
        assert drv.odometry.x == pytest.approx(x, abs=0.03)
        assert drv.odometry.v == pytest.approx(0.4, abs=0.02)
    finally:
        drv.close()
        dev.close()
