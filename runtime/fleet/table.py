"""The fleet's task table, replicated on every robot (sans-IO).

Every task an operator hands to any robot is entered here with a fleet-unique id (``origin << 16 | n``),
broadcast to every peer, and kept by all of them, so a task survives the robot that received it.  An
entry is the mission item it came from (command, params, position in the fleet frame, the frame the
operator used), a state: open, done, withdrawn (cleared before it was done), cleared (done, then the
mission was cleared), and the robots that did it (``done_by``, empty until a robot that did it says so).

The table is a state-based replicated data type: an entry's content never changes once minted (one robot mints
each id; a record that contradicts it is refused by the node), and its two changing fields are each a
join-semilattice, merged field by field:

* ``state`` is two bits, done (1) and removed from the mission (2): open 0, done 1, withdrawn 2, cleared 3, and
  the join is bitwise OR.  For ordered pairs that is the later state; done joined with withdrawn (one robot saw
  it done, the one the operator cleared did not yet) is cleared, as it would be had the news come first;
* ``done_by`` is a set of robot ids, joined by union (the lowest :data:`MAX_BY` ids kept: the wire's eight).

So :meth:`Entry.join` is commutative, associative and idempotent, and any two robots that have merged the same records,
in any order, with any duplicates, hold equal tables (tests/test_fleet_table.py checks it over random records).

Anti-entropy: each robot's :class:`~runtime.messages.RobotState` carries the size and a CRC-32 of its table over
every field that can differ (id, state, done_by); a robot that sees a different digest asks that peer for its
table (``TableRequest``, at most once per ``resync`` seconds per peer) and merges the answer, whose records carry
``done_by`` in ``holders``.  Changes are also broadcast at once.  Bound: once the last change is made and the
peers' messages get through, two robots that hear each other hold equal tables within ``state_period + resync``
(the next RobotState shows the difference, the request goes out unless one went within ``resync``) plus the
delivery of one request and its answer: 3 s and a few delays with the defaults.
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
MAX_BY = 8                    # robots a record's ``holders`` carries (uint8[8] on the wire)


def join_state(a: int, b: int) -> int:
    """The join of two task states (bits: done 1, removed 2): the later of two ordered states; done and withdrawn
    make cleared."""
    return a | b


def join_by(a: tuple[int, ...], b: tuple[int, ...]) -> tuple[int, ...]:
    """The join of two ``done_by`` sets: their union, sorted, the lowest :data:`MAX_BY` ids kept (the lowest k of a
    union is the lowest k of the union of the lowest k of each, so this stays a semilattice)."""
    return tuple(sorted(set(a) | set(b)))[:MAX_BY]


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
    done_by: tuple[int, ...] = ()

    def join(self, state: int, done_by: tuple[int, ...]) -> "Entry":
        """This entry with ``state`` and ``done_by`` merged in (itself if nothing moves)."""
        s, by = join_state(self.state, state), join_by(self.done_by, done_by)
        return self if (s, by) == (self.state, self.done_by) else replace(self, state=s, done_by=by)

    @property
    def task(self) -> T.Task:
        kind = T.kind_of_command(self.command)
        return T.Task(self.id, kind.KIND, kind.from_item(self.command, self.params, self.x, self.y))

    @property
    def listed(self) -> bool:
        """Part of the fleet's mission as a ground station downloads it."""
        return self.state in (OPEN, DONE)

    def record(self, sender: int, dest: int = BROADCAST) -> TaskRecord:
        return TaskRecord(sender, dest, self.id, self.command, self.frame, self.state, *self.params, self.x, self.y,
                          self.done_by)


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

    def mark(self, task_id: int, state: int, by: tuple[int, ...] = ()) -> list:
        """Join ``state`` (done, withdrawn, cleared) and, for a task done here, the robots that did it ``by`` into
        a task; the record to broadcast if that moved it."""
        e = self.entries.get(task_id)
        if e is None:
            return []
        moved = e.join(state, tuple(by))
        if moved is e:
            return []
        self.entries[task_id] = moved
        self._digest = None
        return [moved.record(self.robot_id)]

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
        """Merge a peer's record (its ``holders``: the robots that did the task; of an open task they are a ground
        station's answer, a belief, and never merged).  Returns (the task if it is new to me, its new state if that
        moved)."""
        by = join_by((), rec.holders) if rec.state != OPEN else ()
        e = self.entries.get(rec.task)
        if e is None:
            entry = Entry(rec.task, rec.command, rec.frame, (rec.param1, rec.param2, rec.param3, rec.param4),
                          rec.x, rec.y, rec.state, by)
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
        moved = e.join(rec.state, by)
        if moved is e:
            return None, None
        self.entries[rec.task] = moved
        self._digest = None
        return None, (moved.state if moved.state != e.state else None)

    @property
    def digest(self) -> int:
        if self._digest is None:
            data = b"".join(tid.to_bytes(4, "little") + bytes([e.state, len(e.done_by), *e.done_by])
                            for tid, e in sorted(self.entries.items()))
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

    def done_by(self, task_id: int) -> tuple[int, ...]:
        e = self.entries.get(task_id)
        return () if e is None else e.done_by
