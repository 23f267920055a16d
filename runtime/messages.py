"""The ground floor of the robots' vocabulary: fleet task ids, the broadcast address, and one base for every
message dataclass, whose fields declare their kinds and are validated in one place.

A message is a frozen dataclass, ``sender`` and ``dest`` first, deriving from :class:`Message`; a field declares
its kind with one of the ``Annotated`` types below (``sender: RobotId``, ``task: TaskId``, ``round: Count``,
``capacity: Amount`` ...).  :meth:`Message.invalid` checks the declared fields in order, then the class's own
:meth:`Message.check` (what only its family knows: a value's range, a list's rules), and returns the first reason
(one line: the field, its value, what was expected) or None.  The codec calls it once when a frame is decoded
(:mod:`runtime.comms.codec`, which reads the plain types under the annotations), so handlers trust what they get.
Anchor: h11's ``_EventBundle`` (fields declared once, validated in one place).

Nothing here imports anything else of the runtime: every layer may import it.
"""
from __future__ import annotations

import math
import typing
from dataclasses import dataclass, fields
from typing import Annotated, Callable

BROADCAST = 0                 # ``dest`` of a message for every peer
MAX_ROBOT = 250               # robot ids are 1..250 (MAVLink system ids; 251-255 are ground stations' by custom)
MAX_U32 = 0xFFFFFFFF


def task_origin(task_id: int) -> int:
    """The robot that minted fleet task ``task_id`` (its upper 16 bits)."""
    return task_id >> 16


def fleet_task_id(origin: int, n: int) -> int:
    """The ``n``-th task robot ``origin`` took from an operator."""
    return (int(origin) << 16) | int(n)


def is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def is_finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def is_robot(v) -> bool:
    return is_int(v) and 1 <= v <= MAX_ROBOT


def is_task(v) -> bool:
    return is_int(v) and 1 <= v >> 16 <= MAX_ROBOT


@dataclass(frozen=True)
class Kind:
    """What a field's value must be: ``ok(value)``, and ``expected`` for the reason when it is not (or ``reason``
    to word it otherwise)."""
    expected: str
    ok: Callable[[object], bool]
    reason: Callable[[str, object], str] | None = None

    def why(self, name: str, value) -> str:
        return self.reason(name, value) if self.reason else f"{name} {value!r}: expected {self.expected}"


ROBOT = Kind(f"a robot id 1..{MAX_ROBOT}", is_robot)
DEST = Kind(f"a robot id 0..{MAX_ROBOT} (0: every peer)", lambda v: is_int(v) and 0 <= v <= MAX_ROBOT)
TASK = Kind("a fleet task id (origin robot 1..250 in its upper 16 bits)", is_task)
COUNT = Kind(f"an integer 0..{MAX_U32}", lambda v: is_int(v) and 0 <= v <= MAX_U32)
AMOUNT = Kind("a finite number >= 0", lambda v: is_finite(v) and v >= 0)
NUMBER = Kind("a finite number", is_finite)
ROBOTS = Kind(f"distinct robot ids 1..{MAX_ROBOT}",
              lambda v: isinstance(v, tuple) and all(map(is_robot, v)) and len(set(v)) == len(v))
TASKS = Kind("fleet task ids (origin robot 1..250 in their upper 16 bits)",
             lambda v: isinstance(v, tuple) and all(map(is_task, v)))
PLACE = Kind("a number (NaN: not localized)", lambda v: is_finite(v) or (isinstance(v, float) and math.isnan(v)))

RobotId = Annotated[int, ROBOT]
Dest = Annotated[int, DEST]
TaskId = Annotated[int, TASK]
Count = Annotated[int, COUNT]
Amount = Annotated[float, AMOUNT]
Number = Annotated[float, NUMBER]
RobotIds = Annotated[tuple[int, ...], ROBOTS]
TaskIds = Annotated[tuple[int, ...], TASKS]
Place = Annotated[float, PLACE]

_checks: dict[type, tuple[tuple[str, Kind], ...]] = {}


def declared(cls: type) -> tuple[tuple[str, Kind], ...]:
    """``(field, kind)`` for each field of ``cls`` that declares a kind, in field order (resolved once)."""
    got = _checks.get(cls)
    if got is None:
        hints = typing.get_type_hints(cls, include_extras=True)
        got = tuple((f.name, k) for f in fields(cls) for k in getattr(hints.get(f.name), "__metadata__", ())
                    if isinstance(k, Kind))
        _checks[cls] = got
    return got


class Message:
    """The base of every message dataclass (no fields of its own)."""

    def invalid(self) -> str | None:
        """Why this message cannot be acted on (one line), or None.  Found once per message object (its fields are
        frozen; a broadcast on the in-memory bus is one object that every robot checks)."""
        try:
            return self.__dict__["_invalid"]
        except KeyError:
            pass
        why = self._invalid()
        if type(self).__setattr__ is not object.__setattr__:     # frozen dataclass: the fields cannot change
            object.__setattr__(self, "_invalid", why)
        return why

    def _invalid(self) -> str | None:
        for name, kind in declared(type(self)):
            v = getattr(self, name)
            if not kind.ok(v):
                return kind.why(name, v)
        return self.check()

    def check(self) -> str | None:
        """The family's own checks, after the declared kinds hold."""
        return None


def why_invalid(msg) -> str | None:
    """``msg.invalid()`` for a message that did not come through the codec (in-memory tests hand agents objects the
    codec never made): never raises."""
    try:
        return msg.invalid()
    except Exception as exc:          # values of types the protocol never sends
        return f"malformed: {type(exc).__name__}"


# ---------------------------------------------------------------------- the runtime's own messages

OPEN, DONE, WITHDRAWN, CLEARED = 0, 1, 2, 3          # TaskRecord.state; a later state wins a merge
STATE_NAMES = {OPEN: "open", DONE: "done", WITHDRAWN: "withdrawn", CLEARED: "cleared"}

LOCALIZING, IDLE, ALLOCATING, EXECUTING, DISARMED = range(5)     # RobotState.state
ROBOT_STATE_NAMES = {LOCALIZING: "localizing", IDLE: "idle", ALLOCATING: "allocating", EXECUTING: "executing",
                     DISARMED: "disarmed"}
MAX_HELD = 8            # fleet task ids a RobotState can name

_ORIGIN = Kind("", lambda v: 1 <= task_origin(v) <= MAX_ROBOT,
               lambda name, v: f"task id {v}: expected an origin robot 1..{MAX_ROBOT} in its upper 16 bits")


@dataclass(frozen=True)
class TaskRecord(Message):
    """One fleet task: the mission item it came from (command, params, position in the fleet frame, and the
    frame the operator used) and its state."""
    sender: int
    dest: int
    task: Annotated[int, _ORIGIN]
    command: int
    frame: int
    state: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: float
    y: float
    holders: RobotIds = ()      # a task no longer open: the robots that did it (replicated, runtime/fleet/table.py);
    #                             an open one, in answers to a ground station: the robots the sender believes hold it

    def check(self) -> str | None:
        if self.state not in STATE_NAMES:
            return f"state {self.state}: expected 0..3"
        if not (math.isfinite(self.x) and math.isfinite(self.y)):
            return "position: expected finite x, y"
        return None


@dataclass(frozen=True)
class RobotState(Message):
    """A robot's state (at once when it changes, else every second): what it does, the fleet tasks it holds, where
    it is, and the size and CRC-32 of its task table."""
    sender: RobotId
    dest: Dest
    state: int
    tasks: TaskIds
    x: Place
    y: Place
    known: Count
    digest: Count

    def check(self) -> str | None:
        if self.state not in ROBOT_STATE_NAMES:
            return f"state {self.state!r}: expected 0..4"
        return None


@dataclass(frozen=True)
class TableRequest(Message):
    """A robot whose table digest differs from the sender's asks for its table; with ``task`` (a fleet task id, not
    0) it asks the task's origin for that task's record alone (to confirm a task it heard of from someone else)."""
    sender: int
    dest: int
    digest: int
    task: int = 0


FLEET_MESSAGES = (TaskRecord, RobotState, TableRequest)
