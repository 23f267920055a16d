"""How a held task is carried out: one executor per task kind, and the executive that runs them.

``EXECUTORS`` maps a task kind to ``module:Class``; a new task kind adds its executor here (one line).
"""
from __future__ import annotations

import importlib

EXECUTORS: dict[str, str] = {
    "goto": "runtime.execution.goto:GotoExecutor",
    "rendezvous": "runtime.execution.rendezvous:RendezvousExecutor",
}


def executor_class(kind: str) -> type:
    module, _, cls = EXECUTORS[kind].partition(":")
    return getattr(importlib.import_module(module), cls)
