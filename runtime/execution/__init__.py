"""How a held task is carried out: one executor per task kind, and the executive that runs them.

A task kind's module names its executor (``EXECUTOR = "module:Class"``, e.g. runtime/tasks/goto.py), so a new
kind is its spec module, its executor module and one line in runtime/tasks/__init__.py's ``KINDS``.
"""
from __future__ import annotations

from runtime import tasks
from runtime.lazy import resolve


def executor_class(kind: str) -> type:
    return resolve(tasks.kind(kind).EXECUTOR)
