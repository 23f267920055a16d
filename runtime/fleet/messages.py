"""The runtime's own messages between robots (and to the ground station): the fleet task table and each
robot's state.  Frozen dataclasses, ``sender`` and ``dest`` first (dest 0 = every peer); each is validated
once when decoded (``invalid()``)."""
from __future__ import annotations

import math
from dataclasses import dataclass

BROADCAST = 0
OPEN, DONE, WITHDRAWN, CLEARED = 0, 1, 2, 3          # TaskRecord.state; a later state wins a merge
STATE_NAMES = {OPEN: "open", DONE: "done", WITHDRAWN: "withdrawn", CLEARED: "cleared"}

LOCALIZING, IDLE, ALLOCATING, EXECUTING, DISARMED = range(5)     # RobotState.state
ROBOT_STATE_NAMES = {LOCALIZING: "localizing", IDLE: "idle", ALLOCATING: "allocating", EXECUTING: "executing",
                     DISARMED: "disarmed"}
MAX_HELD = 8            # fleet task ids a RobotState can name


def task_origin(task_id: int) -> int:
    return task_id >> 16


@dataclass(frozen=True)
class TaskRecord:
    """One fleet task: the mission item it came from (command, params, position in the fleet frame, and the
    frame the operator used) and its state."""
    sender: int
    dest: int
    task: int
    command: int
    frame: int
    state: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: float
    y: float
    holders: tuple[int, ...] = ()      # the sender's belief, in answers to a ground station

    def invalid(self) -> str | None:
        if not 1 <= task_origin(self.task) <= 250:
            return f"task id {self.task}: expected an origin robot 1..250 in its upper 16 bits"
        if self.state not in STATE_NAMES:
            return f"state {self.state}: expected 0..3"
        if not (math.isfinite(self.x) and math.isfinite(self.y)):
            return "position: expected finite x, y"
        return None


@dataclass(frozen=True)
class RobotState:
    sender: int
    dest: int
    state: int
    tasks: tuple[int, ...]
    x: float
    y: float
    known: int
    digest: int

    def invalid(self) -> str | None:
        if self.state not in ROBOT_STATE_NAMES:
            return f"state {self.state}: expected 0..4"
        if any(not 1 <= task_origin(t) <= 250 for t in self.tasks):
            return f"tasks {list(self.tasks)}: expected fleet task ids"
        return None


@dataclass(frozen=True)
class TableRequest:
    sender: int
    dest: int
    digest: int


FLEET_MESSAGES = (TaskRecord, RobotState, TableRequest)
