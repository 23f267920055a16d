"""What work is: tasks, what a robot commits to, and how execution reports back.  Pure data.

* :class:`Task` - frozen ``(id, kind, spec)``; ``spec`` is the kind's own frozen dataclass
  (:mod:`runtime.tasks.goto`, :mod:`runtime.tasks.rendezvous`).  Fleet task ids are unique in the fleet:
  ``origin << 16 | n`` for the n-th task robot ``origin`` accepted from an operator.
* :class:`Profile` - what a robot brings to an estimate: cruise speed and footprint.
* :class:`Estimate` - a kind's pure estimate of what a task costs this robot (metres of travel for
  motion tasks) and how long it takes (seconds).
* :class:`Commitment` - what an allocation agent hands to execution: the task, the robots it shares it
  with (a coalition; empty when alone), this robot's role in it and the role's parameters (``params``:
  ``(name, value)`` pairs the kind's executor reads, e.g. a transport's load per trip).  A robot may hold
  several.
* :class:`Progress` - what execution reports back to the agent: ``arrived``, ``done``, ``failed``
  (``detail`` says why), with the time.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

Travel = Callable[[float, float], float]      # metres of path from the robot's pose to (x, y); inf: no path

ARRIVED, DONE, FAILED = "arrived", "done", "failed"


@dataclass(frozen=True)
class Task:
    id: int
    kind: str
    spec: Any

    @property
    def position(self) -> tuple[float, float] | None:
        """Where the task is, for kinds that have a place (x, y in the fleet frame, metres)."""
        xy = getattr(self.spec, "x", None), getattr(self.spec, "y", None)
        return None if None in xy else (float(xy[0]), float(xy[1]))


@dataclass(frozen=True)
class Profile:
    speed: float                 # m/s cruise
    radius: float                # m, footprint


@dataclass(frozen=True)
class Estimate:
    cost: float                  # metres of travel (inf: cannot)
    duration: float              # seconds (inf: cannot)


@dataclass(frozen=True)
class Commitment:
    task: Task
    partners: tuple[int, ...] = ()      # the other robots of the coalition
    role: str = "solo"
    params: tuple[tuple[str, Any], ...] = ()     # (name, value) pairs for the executor; hashable

    def param(self, name: str, default: Any = None) -> Any:
        return next((v for k, v in self.params if k == name), default)

    @property
    def task_id(self) -> int:
        return self.task.id


@dataclass(frozen=True)
class Progress:
    task: int
    event: str                   # ARRIVED | DONE | FAILED
    t: float
    detail: str = ""
    data: dict = field(default_factory=dict, compare=False)
