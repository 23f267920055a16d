"""Lazy ``"package.module:Attribute"`` references, as the registries (drivers, SITL devices and bodies)
hold them: the module is imported only when the entry is used, so a robot that drives a Create never
imports another base's stack."""
from __future__ import annotations

import importlib


def resolve(ref: str):
    """The attribute ``ref`` = ``"package.module:Attribute"`` names, importing its module."""
    module, _, attr = ref.partition(":")
    return getattr(importlib.import_module(module), attr)
