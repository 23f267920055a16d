"""Task kinds: the only list of them.  A new kind is one module here plus one line in ``KINDS``.

Each kind module has ``KIND`` (its name), ``Spec`` (frozen dataclass), ``COMMANDS`` (the MAVLink mission
commands that create it), ``EXECUTOR`` (``"module:Class"`` of the executor that carries it out, in
runtime/execution/), ``estimate(spec, profile, travel)``, ``from_item(command, params, x, y)`` (raises
ValueError with a one-line reason for bad params) and ``to_item(spec)``.
"""
from __future__ import annotations

import importlib
from types import ModuleType

from runtime.tasks.model import (ARRIVED, DONE, FAILED, Commitment, Estimate, Profile, Progress, Task,  # noqa: F401
                                 Travel)

KINDS: dict[str, str] = {
    "goto": "runtime.tasks.goto",
    "rendezvous": "runtime.tasks.rendezvous",
    "transport": "runtime.tasks.transport",
    "surveillance": "runtime.tasks.surveillance",            # paper 003: visit every waypoint of a region
    "avoid_obstacles": "runtime.tasks.avoid_obstacles",      # paper 003: keep a robot clear of obstacles
}


def kind(name: str) -> ModuleType:
    return importlib.import_module(KINDS[name])


def kind_of_command(command: int) -> ModuleType | None:
    """The kind a mission item's command creates, or None if no kind takes it."""
    for name in KINDS:
        mod = kind(name)
        if command in mod.COMMANDS:
            return mod
    return None


def estimate(task: Task, profile: Profile, travel: Travel) -> Estimate:
    return kind(task.kind).estimate(task.spec, profile, travel)
