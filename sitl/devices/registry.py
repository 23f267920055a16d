"""SITL devices by ``base.type`` (the same names as runtime.drivers.registry)."""
from __future__ import annotations

import importlib

DEVICES = {"create_oi": "sitl.devices.create_oi:CreateOIDevice"}
BODIES = {"create_oi": "create2"}


def body_kind(base_cfg) -> str:
    return BODIES[base_cfg.type]


def make_device(base_cfg, body, robot_id: int):
    module, _, cls = DEVICES[base_cfg.type].partition(":")
    return getattr(importlib.import_module(module), cls).from_config(base_cfg, body, robot_id)
