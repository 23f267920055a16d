"""Base drivers by ``base.type``: the only list of them.

Each entry names ``module:Class``; the module is imported only when that type is used (as python-can's
``BACKENDS`` does), so a robot that drives a Create never imports the CAN stack.  The class is a
:class:`runtime.drivers.base.MobileBase` with a ``Config`` attribute: the frozen dataclass that is the
schema of the robot config's ``base:`` section for that type (its ``type`` field is a one-value Literal),
and a ``from_config(cfg, robot_id)`` constructor.  A new base is one driver module plus one line here.
"""
from __future__ import annotations

import importlib

BASES: dict[str, str] = {
    "create_oi": "runtime.drivers.create_oi:CreateOI",      # iRobot Create 2 / Create 1, Open Interface
}


def driver_class(type_name: str) -> type:
    module, _, cls = BASES[type_name].partition(":")
    return getattr(importlib.import_module(module), cls)


def config_classes() -> dict[str, type]:
    """``{base.type: its config dataclass}`` (the robot config's ``base:`` union)."""
    return {name: driver_class(name).Config for name in BASES}


def open_base(cfg, robot_id: int):
    """The driver for ``cfg`` (a ``base:`` config of any registered type), not yet opened."""
    return driver_class(cfg.type).from_config(cfg, robot_id)
