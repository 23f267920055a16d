"""The fleet's task table, replicated on every robot (sans-IO).

Every task an operator hands to any robot is entered here with a fleet-unique id (``origin << 16 | n``),
broadcast to every peer, and kept by all of them, so a task survives the robot that received it.  An
entry is the mission item it came from (command, params, position in the fleet frame, the frame the
operator used) and a state: open, done, withdrawn (cleared before it was done), cleared (done, then the
mission was cleared).  States only move forward (a later state wins), so merging two tables in any order
gives the same table: the replicas converge whatever the loss, duplication or order of messages.

Anti-entropy: each robot's :class:`~runtime.messages.RobotState` carries the size and a CRC-32 of
its table; a robot that sees a different digest asks that peer for its table (``TableRequest``, at most
once per ``resync`` seconds per peer) and merges the answer.  Changes are also broadcast at once.
"""
from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass, replace

from runtime import tasks as T
from runtime.messages import BROADCAST, CLEARED, DONE, OPEN, WITHDRAWN, TaskRecord, task_origin
from runtime.log import get_logger

MAX_PER_ORIGIN = 0xFFFF


def _same_f32(a: float, b: float) -> bool:
    """Equal at float32 (how TaskRecord carries values), NaN equal to NaN (unused mission parameters)."""
    try:
        a, b = struct.unpack("<2f", struct.pack("<2f", a, b))
    except OverflowError:            # beyond float32: compare as they are
        pass
    return a == b or (math.isnan(a) and math.isnan(b))


@dataclass(frozen=True)
class Entry:
    id: int
    command: int
    frame: int
    params: tuple[float, float, float, float]
    x: float
    y: float
    state: int = OPEN

    @property
    def task(self) -> T.Task:
        kind = T.kind_of_command(self.command)
        return T.Task(self.id, kind.KIND, kind.from_item(self.command, self.params, self.x, self.y))

    @property
    def listed(self) -> bool:
        """Part of the fleet's mission as a ground station downloads it."""
        return self.state in (OPEN, DONE)

    def record(self, sender: int, dest: int = BROADCAST) -> TaskRecord:
        return TaskRecord(sender, dest, self.id, self.command, self.frame, self.state, *self.params, self.x, self.y)


class TaskTable:
    def __init__(self, robot_id: int, resync: float = 2.0):
        self.robot_id = int(robot_id)
        self.resync = float(resync)
        self.entries: dict[int, Entry] = {}
        self.dropped = 0                         # records that do not make a task (unknown command, bad params)
        self._asked: dict[int, float] = {}       # peer -> when I last asked it for its table
        self._digest: int | None = None
        self.log = get_logger("fleet.table", self.robot_id)

    # ------------------------------------------------------------------ local changes
    def add(self, items: list[tuple[int, int, tuple[float, float, float, float], float, float]]) -> tuple[list[T.Task], list]:
        """Enter operator items ``(command, frame, params, x, y)`` as new open tasks.  Returns the tasks and the
        records to broadcast."""
        n = max((t & MAX_PER_ORIGIN for t in self.entries if task_origin(t) == self.robot_id), default=0)
        if n + len(items) > MAX_PER_ORIGIN:
            raise OverflowError(f"robot {self.robot_id} has handed out all its {MAX_PER_ORIGIN} task ids")
        out, new = [], []
        for k, (command, frame, params, x, y) in enumerate(items, start=n + 1):
            e = Entry(self.robot_id << 16 | k, int(command), int(frame), tuple(float(p) for p in params), float(x),
                      float(y))
            self.entries[e.id] = e
            new.append(e.task)
            out.append(e.record(self.robot_id))
        self._digest = None
        return new, out

    def mark(self, task_id: int, state: int) -> list:
        """Move a task to ``state`` (done, withdrawn, cleared) if that is forward; the records to broadcast."""
        e = self.entries.get(task_id)
        if e is None or state <= e.state:
            return []
        self.entries[task_id] = replace(e, state=state)
        self._digest = None
        return [self.entries[task_id].record(self.robot_id)]

    def clear(self) -> tuple[list[int], list]:
        """The operator cleared the mission: open tasks are withdrawn, done ones cleared.  Returns the ids
        withdrawn and the records to broadcast."""
        out, withdrawn = [], []
        for tid, e in sorted(self.entries.items()):
            if e.state == OPEN:
                withdrawn.append(tid)
                out += self.mark(tid, WITHDRAWN)
            elif e.state == DONE:
                out += self.mark(tid, CLEARED)
        return withdrawn, out

    # ------------------------------------------------------------------ replication
    def contradicts(self, rec: TaskRecord) -> bool:
        """A record of a task I know with other content (command, frame, parameters, position), as far as the
        wire's float32 carries it."""
        e = self.entries.get(rec.task)
        if e is None:
            return False
        mine = (*e.params, e.x, e.y)
        theirs = (rec.param1, rec.param2, rec.param3, rec.param4, rec.x, rec.y)
        return (e.command, e.frame) != (rec.command, rec.frame) or not all(map(_same_f32, mine, theirs))

    def merge(self, rec: TaskRecord) -> tuple[T.Task | None, int | None]:
        """Merge a peer's record.  Returns (the task if it is new to me, its new state if that moved)."""
        e = self.entries.get(rec.task)
        if e is None:
            entry = Entry(rec.task, rec.command, rec.frame, (rec.param1, rec.param2, rec.param3, rec.param4),
                          rec.x, rec.y, rec.state)
            try:
                task = entry.task
            except (AttributeError, ValueError, TypeError) as exc:    # no kind takes it, or bad params
                self.dropped += 1
                self.log.warning("task %d from robot %d dropped: %s", rec.task, rec.sender,
                                 exc if isinstance(exc, ValueError) else f"command {rec.command} makes no task")
                return None, None
            self.entries[rec.task] = entry
            self._digest = None
            return task, rec.state
        if rec.state > e.state:
            self.entries[rec.task] = replace(e, state=rec.state)
            self._digest = None
            return None, rec.state
        return None, None

    @property
    def digest(self) -> int:
        if self._digest is None:
            data = b"".join(tid.to_bytes(4, "little") + bytes([e.state]) for tid, e in sorted(self.entries.items()))
            self._digest = zlib.crc32(data)
        return self._digest

    def compare(self, peer: int, known: int, digest: int, now: float) -> list:
        """A peer's table summary: ask it for its table if ours differ (rate-limited per peer)."""
        from runtime.messages import TableRequest

        if digest == self.digest and known == len(self.entries):
            return []
        if now - self._asked.get(peer, -math.inf) < self.resync:
            return []
        self._asked[peer] = now
        return [TableRequest(self.robot_id, peer, self.digest)]

    def records(self, dest: int) -> list[TaskRecord]:
        return [e.record(self.robot_id, dest) for _, e in sorted(self.entries.items())]

    # ------------------------------------------------------------------ views
    def listing(self) -> list[Entry]:
        """The fleet's mission as downloaded: open and done tasks by id (``seq`` = position here)."""
        return [e for _, e in sorted(self.entries.items()) if e.listed]

    def seq(self, task_id: int) -> int | None:
        for i, e in enumerate(self.listing()):
            if e.id == task_id:
                return i
        return None

    def open_tasks(self) -> list[T.Task]:
        return [e.task for _, e in sorted(self.entries.items()) if e.state == OPEN]

    def state(self, task_id: int) -> int | None:
        e = self.entries.get(task_id)
        return None if e is None else e.state
