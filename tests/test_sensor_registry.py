"""The sensor registries: every sensor type has a driver with a well-formed Config and a SITL device whose
endpoint is a config of that driver which reads the device."""
from __future__ import annotations

import dataclasses
import typing

import pytest

from runtime import config as C
from runtime.drivers import registry as drivers

pytest.importorskip("pybullet")
from sitl.devices import registry as devices  # noqa: E402
from sitl.world import World  # noqa: E402

SENSOR_TYPES = sorted(drivers.SENSORS)


@pytest.mark.parametrize("name", SENSOR_TYPES)
def test_driver_config_is_tagged_by_its_key_and_the_device_twin_exists(name):
    cls = drivers.sensor_class(name)
    cfg_cls = cls.Config
    assert dataclasses.is_dataclass(cfg_cls) and cfg_cls.__dataclass_params__.frozen
    hints = typing.get_type_hints(cfg_cls)
    assert typing.get_args(hints["type"]) == (name,) and cfg_cls().type == name
    for attr in ("from_config", "open", "poll", "close"):
        assert callable(getattr(cls, attr, None)), attr
    assert isinstance(cls.kind, str) and cls.kind and cls.reports in ("fixes", "ranges")
    assert cls.reports == "fixes" or callable(getattr(cls, "ranges", None))
    assert set(devices.SENSOR_DEVICES) == set(drivers.SENSORS)


@pytest.mark.parametrize("name", SENSOR_TYPES)
def test_a_device_endpoint_is_a_driver_config_that_reads_it(name):
    cfg_cls = drivers.sensor_class(name).Config
    with World(C.WorldConfig(size=(4.0, 4.0)), wheel_radius_sigma=0.0) as w:
        body = w.add_body(2, (0.0, 0.0, 0.0), "create2")
        dev = devices.make_sensor_device(cfg_cls(), body, 2)
        drv = drivers.sensor_class(name).from_config(dataclasses.replace(cfg_cls(), **dev.endpoint()), 2)
        try:
            drv.open(0.0)
            t, got = 0.0, []
            for i in range(300):
                t += 0.005
                dev.service(t)
                if i % 10 == 0:
                    got += drv.poll(t)
            assert got and drv.usable
        finally:
            drv.close()
            dev.close()


def test_an_unknown_sensor_type_has_no_device():
    from runtime.errors import InputError

    @dataclasses.dataclass(frozen=True)
    class Nope:
        type: str = "sonar_x"

    with pytest.raises(InputError, match="sensors type 'sonar_x': expected one with a SITL device, one of nmea_gps, rplidar"):
        devices.make_sensor_device(Nope(), None, 1)
