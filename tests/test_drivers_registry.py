"""The base registries: every base type has a driver with a well-formed Config, a SITL device and a body;
the robot config's base union is exactly the registry; a device's endpoint is a base config that works."""
from __future__ import annotations

import dataclasses
import time
import typing

import pytest
import yaml

from runtime import config as C
from runtime.config import ConfigError
from runtime.drivers import registry as drivers
from runtime.drivers.base import Footprint, MobileBase
from runtime.errors import InputError
from sitl.bodies import registry as bodies
from sitl.devices import registry as devices
from tests.fakes import FakeBody

BASE_TYPES = sorted(drivers.BASES)


@pytest.mark.parametrize("name", BASE_TYPES)
def test_driver_imports_with_a_config_whose_type_is_its_key(name):
    cls = drivers.driver_class(name)
    assert issubclass(cls, MobileBase)
    cfg_cls = cls.Config
    assert dataclasses.is_dataclass(cfg_cls) and cfg_cls.__dataclass_params__.frozen
    hints = typing.get_type_hints(cfg_cls)
    assert typing.get_origin(hints["type"]) is typing.Literal and typing.get_args(hints["type"]) == (name,)
    cfg = cfg_cls()                                       # every field has a default
    assert cfg.type == name
    base = cls.from_config(cfg, 3)
    assert isinstance(base, MobileBase) and isinstance(base.footprint, Footprint)
    assert not base.is_open


def test_the_robot_config_base_union_is_the_registry():
    assert set(drivers.config_classes()) == set(drivers.BASES)
    assert C.RobotConfig().base.type in drivers.BASES


def test_an_unknown_base_type_is_one_line_naming_the_known_ones(tmp_path):
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump({"base": {"type": "nope"}}))
    with pytest.raises(ConfigError) as info:
        C.load_robot(path)
    assert str(info.value) == f"{path}: base.type: expected one of {'|'.join(drivers.BASES)}, got 'nope'"
    assert "\n" not in str(info.value) and "create_oi" in str(info.value)


@pytest.mark.parametrize("name", BASE_TYPES)
def test_every_base_type_has_a_device_and_a_body(name):
    assert set(devices.DEVICES) == set(drivers.BASES)
    dev_cls = devices.device_class(name)
    for attr in ("from_config", "body_kind", "service", "close", "endpoint"):
        assert callable(getattr(dev_cls, attr, None)), attr
    kind = devices.body_kind(drivers.driver_class(name).Config())
    assert kind in bodies.BODIES
    assert bodies.body_class(kind).radius > 0


def test_unknown_kinds_are_input_errors():
    with pytest.raises(InputError, match="one of create_oi"):
        devices.device_class("nope")
    with pytest.raises(InputError, match="one of create2"):
        bodies.body_class("nope")


# ----------------------------------------------------------------------------- make_device + endpoint
def _robot_config(base: dict):
    return C.from_dict(C.RobotConfig, {"base": base}, "<generated>")


@pytest.mark.parametrize("model, baudrate, expected", [
    ("create2", None, 115200), ("create1", None, 57600), ("create2", 57600, 57600),
])
def test_endpoint_is_the_base_config_the_launcher_writes(model, baudrate, expected):
    template = _robot_config({"type": "create_oi", "model": model, "baudrate": baudrate})
    dev = devices.make_device(template.base, FakeBody(), robot_id=4)
    try:
        ep = dev.endpoint()
        assert ep == {"port": dev.path, "baudrate": expected}
        merged = C.deep_merge(C.to_dict(template), {"base": ep})
        cfg = _robot_config(merged["base"])
        assert (cfg.base.port, cfg.base.baudrate, cfg.base.model) == (dev.path, expected, model)
    finally:
        dev.close()


def test_a_driver_opened_on_the_endpoint_drives_the_device():
    """The seam end to end: config -> body kind -> device -> endpoint -> config -> driver -> device."""
    base_cfg = _robot_config({"type": "create_oi"}).base
    assert devices.body_kind(base_cfg) == "create2"
    body = FakeBody()
    dev = devices.make_device(base_cfg, body, robot_id=2)
    drv = drivers.open_base(_robot_config({"type": "create_oi", **dev.endpoint()}).base, 2)
    try:
        drv.open(0.0)
        drv.set_velocity(0.2, 0.0, 0.0)
        deadline = time.monotonic() + 2.0
        while body.cmd != (0.2, 0.2) and time.monotonic() < deadline:
            dev.service(0.0)
            drv.poll(0.0)
            time.sleep(0.001)
        assert dev.mode_name == "safe" and body.cmd == (0.2, 0.2)
    finally:
        drv.close()
        dev.close()


def test_make_device_on_a_world_body():
    from sitl.world import World
    base_cfg = _robot_config({"type": "create_oi", "model": "create1"}).base
    with World(C.WorldConfig(size=(4.0, 4.0)), wheel_radius_sigma=0.0) as world:
        body = world.add_body(5, (0.0, 0.0, 0.0), devices.body_kind(base_cfg))
        dev = devices.make_device(base_cfg, body, 5)
        try:
            dev.service(world.t)
            assert dev.model == "create1" and dev.endpoint()["baudrate"] == 57600
        finally:
            dev.close()
