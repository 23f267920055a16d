"""A robot's place in the fleet (sans-IO): the replicated task table, the allocation agent, and the state it
tells its peers and the ground station.

The daemon feeds it the operator's uploads, every decoded message from peers, lost peers, progress from
execution and the arm/disarm switch; it returns the messages to send.  Between it and the agent sits the
task table: a task entered here or learnt from a peer is handed to the agent (``add_tasks``) on every
robot, a task done or withdrawn anywhere is taken back (``withdraw_tasks``), and a task the agent reports
done is marked in the table and broadcast.  The same object runs in the daemon and, with a simulated
executor, on the in-memory bus in tests.

Given its configured ``peers`` (and the robots that joined since: :meth:`FleetNode.on_peer_joined`), it takes
messages only from them, and only fleet task ids (minted by a robot of
the fleet, upper 16 bits); a task record that contradicts the table (same id, another command, frame,
parameters or position) is dropped: a task's content never changes once entered, only its state and who did it
(both merged as :mod:`runtime.fleet.table` says).  Each drop is
counted in :attr:`FleetNode.dropped`.  So a robot drives only to tasks in its table, which only operator uploads
and the replication of its peers' tables fill.

A task that a robot hears of from another robot than the one that minted it (its origin, the id's upper 16 bits)
is held, not entered, until the origin confirms it: the robot asks the origin for that one record
(``TableRequest`` with ``task``, again every ``resync`` s) and enters the task when the origin sends it; a record the
origin never confirms is dropped after :data:`UNCONFIRMED` s, counted.  (A robot that missed the origin's broadcast
learns the task so, one request later, through the anti-entropy of the table.)  The task of an origin that is lost
(silent) is taken once two different peers have sent it, since the origin cannot answer any more.  The origin is
the authority on its own ids: a record of my own origin that I never minted, heard after :data:`OWN_GRACE` s from
my start (before that it is a restarted robot learning its own tasks back), is disowned: entered as withdrawn
and that record broadcast, so a decoy forged in my name is withdrawn on every robot within the table's bound.
What signing alone stops: a forged new task in the name of its origin reaches the robots it is sent to until the
origin disowns it; a forged later state (done, withdrawn) or another doer for a known task.
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, replace

from runtime.allocation.agent import AWARDED, DONE, TaskEvent
from runtime.messages import (ALLOCATING, BROADCAST, DISARMED, DONE as T_DONE, EXECUTING, IDLE, LOCALIZING,
                                    MAX_HELD, OPEN, WITHDRAWN, RobotState, TableRequest, TaskRecord, task_origin)
from runtime.fleet.table import TaskTable
from runtime.log import get_logger
from runtime.tasks import Progress

UNCONFIRMED = 30.0          # s a task record its origin has not confirmed is held before it is dropped
OWN_GRACE = 10.0            # s after start in which records of my own origin that I never minted are taken


@dataclass
class _Pending:
    """A task record heard from someone other than its origin, or unasked: held until the origin confirms it."""
    record: TaskRecord
    since: float
    asked: float = -math.inf             # when I last asked the origin for it
    relays: frozenset = frozenset()      # peers that sent it


@dataclass(frozen=True)
class Notice:
    """Something a ground station should hear about: a STATUSTEXT line, and for arrivals the mission seq."""
    text: str
    severity: int = 6                 # MAV_SEVERITY_INFO
    reached_seq: int | None = None    # MISSION_ITEM_REACHED


class FleetNode:
    def __init__(self, robot_id: int, agent, *, state_period: float = 1.0, armed: bool = True, peers=None):
        self.robot_id = int(robot_id)
        self.peers = None if peers is None else frozenset(int(p) for p in peers) - {self.robot_id}
        self.dropped: Counter = Counter()          # peer messages not taken, by reason
        self.agent = agent
        self.table = TaskTable(self.robot_id)
        self.state_period = float(state_period)
        self.armed = bool(armed)
        self.paused = False                         # the operator stopped it (HOLD, RTL): armed, takes no tasks
        self.localized = False
        self.pose: tuple[float, float] | None = None
        self.notices: list[Notice] = []
        self.events: list[TaskEvent] = []          # every agent event, for the run's trace
        self.holding: dict[int, tuple[int, ...]] = {}   # peer -> the tasks its last RobotState named
        self.positions: dict[int, tuple[float, float, float]] = {}   # peer -> (x, y, when) of its last RobotState
        self._last_state: tuple | None = None
        self._next_state = -math.inf
        self._pending: dict[int, _Pending] = {}     # task id -> a record held until its origin confirms it
        self._lost: set[int] = set()                 # peers declared lost and not heard since
        self._started: float | None = None
        self._changed = True                        # an input since the last tick (the tick's state may differ)
        self._quiet = getattr(agent, "quiet", None)  # agents that say when a tick would do nothing
        self.log = get_logger("fleet", self.robot_id)
        if not self.armed:
            agent.set_available(False, 0.0)

    # ------------------------------------------------------------------ the operator
    def add_items(self, items, now: float) -> list:
        """An accepted upload: ``(command, frame, params, x, y)`` per item, fleet frame.  Returns messages."""
        self._changed = True
        tasks, out = self.table.add(items)
        out += self.agent.add_tasks(tasks, now)
        self.log.info("operator handed in %d task(s): %s", len(tasks), [t.id for t in tasks])
        return out

    def clear(self, now: float) -> list:
        self._changed = True
        withdrawn, out = self.table.clear()
        if withdrawn:
            out += self.agent.withdraw_tasks(withdrawn, now)
            self.notices.append(Notice(f"mission cleared: {len(withdrawn)} task(s) withdrawn", 5))
        return out

    def set_armed(self, armed: bool, now: float) -> list:
        self._changed = True
        if armed == self.armed:
            return []
        self.armed = bool(armed)
        says = "armed: taking tasks again" if not self.paused else "armed (paused: taking no tasks)"
        self.notices.append(Notice(says if armed else "disarmed: stopped, tasks released", 4))
        return self.agent.set_available(armed and not self.paused, now) + self._state_now(now)

    def set_paused(self, paused: bool, now: float, says: str) -> list:
        """The operator stops the robot taking tasks (its tasks go back to the fleet) or lets it take them again;
        ``says``: the STATUSTEXT line."""
        self._changed = True
        if paused == self.paused:
            return []
        self.paused = bool(paused)
        self.notices.append(Notice(says, 5))
        return self.agent.set_available(self.armed and not paused, now) + self._state_now(now)

    # ------------------------------------------------------------------ peers
    def on_message(self, msg, now: float) -> list:
        self._changed = True
        why = self._refuse(msg)
        if why is not None:
            self.dropped[why] += 1
            self.log.debug("dropped %s from robot %s: %s", type(msg).__name__, getattr(msg, "sender", None), why)
            return []
        self._lost.discard(msg.sender)
        if isinstance(msg, TaskRecord):
            held = self._pending.get(msg.task)
            if held is not None and msg.sender == task_origin(msg.task) and msg.state & WITHDRAWN:
                msg = replace(held.record, sender=msg.sender, state=msg.state, holders=())   # disowned by its origin
            if msg.task not in self.table.entries and not self._confirmed(msg, now):
                return self._hold(msg, now)
            self._pending.pop(msg.task, None)
            task, state = self.table.merge(msg)
            out = []
            if task is not None and state == OPEN:
                out += self.agent.add_tasks([task], now)
            elif state is not None and state != OPEN:
                out += self.agent.withdraw_tasks([msg.task], now)
            return out
        if isinstance(msg, TableRequest):
            if msg.task:
                e = self.table.entries.get(msg.task)
                if e is None and task_origin(msg.task) == self.robot_id and not self._confirmed(msg, now):
                    return self._disown(msg.task, msg.sender)     # a peer holds a decoy in my name
                return [] if e is None else [e.record(self.robot_id, msg.sender)]
            return [] if msg.digest == self.table.digest else self.table.records(msg.sender)
        if isinstance(msg, RobotState):
            self.holding[msg.sender] = tuple(msg.tasks)
            self.positions[msg.sender] = (float(msg.x), float(msg.y), now)
            return self.table.compare(msg.sender, msg.known, msg.digest, now) + self.agent.on_message(msg, now)
        return self.agent.on_message(msg, now)

    def _refuse(self, msg) -> str | None:
        """Why a peer's message cannot be taken, or None."""
        if self.peers is None:
            return None
        if getattr(msg, "sender", None) not in self.peers:
            return "not a robot of the fleet"
        tasks = (msg.task,) if isinstance(msg, TaskRecord) else msg.tasks if isinstance(msg, RobotState) else ()
        if any(task_origin(t) not in self.peers and task_origin(t) != self.robot_id for t in tasks):
            return "a task no robot of the fleet minted"
        if isinstance(msg, TaskRecord) and self.table.contradicts(msg):
            return "contradicts the task table"
        return None

    def _confirmed(self, rec: TaskRecord, now: float) -> bool:
        """A record of a task new to me may be entered (see the module docstring): from its origin; of my own origin
        within OWN_GRACE of my start; of a lost origin, sent by two peers."""
        origin = task_origin(rec.task)
        if origin == self.robot_id:
            return self._started is None or now - self._started <= OWN_GRACE
        if rec.sender == origin:
            return True
        held = self._pending.get(rec.task)
        return origin in self._lost and held is not None and bool(held.relays - {rec.sender})

    def _hold(self, rec: TaskRecord, now: float) -> list:
        """Hold a relayed record until its origin confirms it and ask the origin for it; disown one of my own
        origin that I never minted."""
        origin = task_origin(rec.task)
        if origin == self.robot_id:
            self.table.merge(replace(rec, state=rec.state | WITHDRAWN, holders=()))
            return self._disown(rec.task, rec.sender)
        held = self._pending.get(rec.task)
        if held is None:
            held = self._pending[rec.task] = _Pending(rec, now)
        held.relays |= {rec.sender}
        return self._ask(rec.task, held, now)

    def _disown(self, task_id: int, sender: int) -> list:
        """A task of my own origin that I never minted: withdrawn, that record broadcast (with what a peer sent, if
        it sent the record; else it only asked me, and my withdrawn record of it says what it holds is no task)."""
        self.dropped["a task of my own origin I never minted"] += 1
        self.log.warning("task %s: robot %d knows a task of mine I never minted: withdrawn fleet-wide",
                         _tid(task_id), sender)
        e = self.table.entries.get(task_id)
        if e is not None:
            return [e.record(self.robot_id)]
        return [TaskRecord(self.robot_id, sender, task_id, 0, 0, WITHDRAWN, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)]

    def _ask(self, task_id: int, held: _Pending, now: float) -> list:
        origin = task_origin(task_id)
        if origin in self._lost or now - held.asked < self.table.resync:
            return []
        held.asked = now
        return [TableRequest(self.robot_id, origin, self.table.digest, task_id)]

    def _pending_tick(self, now: float) -> list:
        """Ask again for held records; drop those unconfirmed for UNCONFIRMED s."""
        out = []
        for tid, held in list(self._pending.items()):
            if now - held.since > UNCONFIRMED:
                del self._pending[tid]
                self.dropped["a task its origin never confirmed"] += 1
                self.log.warning("task %s from robot %d dropped: its origin robot %d never confirmed it",
                                 _tid(tid), held.record.sender, task_origin(tid))
            else:
                out += self._ask(tid, held, now)
        return out

    def on_peer_joined(self, robot_id: int, now: float) -> list:
        """A robot outside the roster joined the fleet (the core saw its first message over a transport that lets
        robots join): its messages are taken from now, and the agent is told (the family decides what a join
        means; an agent without ``on_peer_joined`` keeps its roster).  It is sent my state at once: a robot that
        just started learns the fleet from the first state of each robot (and its table from their digests), not a
        state period later."""
        self._changed = True
        if self.peers is not None:
            self.peers |= {int(robot_id)}
        self._lost.discard(robot_id)
        join = getattr(self.agent, "on_peer_joined", None)
        return ([] if join is None else join(robot_id, now)) + [self.robot_state(int(robot_id))]

    def on_peer_lost(self, robot_id: int, now: float) -> list:
        self._changed = True
        self._lost.add(robot_id)
        self.holding.pop(robot_id, None)
        self.positions.pop(robot_id, None)
        return self.agent.on_peer_lost(robot_id, now)

    def holders(self, task_id: int) -> tuple[int, ...]:
        """Robots holding ``task_id``, as far as I know (me, and peers by their last state)."""
        who = [self.robot_id] if task_id in self.held() else []
        return tuple(sorted(who + [r for r, tasks in self.holding.items() if task_id in tasks]))

    def answer_table(self, dest: int) -> list[TaskRecord]:
        """The table for a ground station: every task with the robots I believe hold it (a task no longer open:
        the robots that did it, as the replicated table says; none if it was never done or no robot that did it
        has been heard yet)."""
        return [replace(r, holders=self.holders(r.task)[:MAX_HELD]) if r.state == OPEN else r
                for r in self.table.records(dest)]

    @property
    def done_by(self) -> dict[int, tuple[int, ...]]:
        """Tasks the table knows to have been done, and by whom (replicated: the same on every robot)."""
        return {tid: e.done_by for tid, e in self.table.entries.items() if e.done_by}

    def on_progress(self, p: Progress, now: float) -> list:
        self._changed = True
        if p.event == "arrived":
            seq = self.table.seq(p.task)
            self.notices.append(Notice(f"task {_tid(p.task)} reached", 6, seq))
        return self.agent.on_progress(p, now)

    # ------------------------------------------------------------------ each cycle
    def begin(self, pose: tuple[float, float] | None) -> None:
        """The pose estimate of this cycle (None: not localized yet), before any input is handled."""
        self.pose = pose
        if self.localized != (pose is not None):
            self._changed = True
        self.localized = pose is not None
        setter = getattr(self.agent, "set_localized", None)
        if setter is not None:
            setter(self.localized)

    def tick(self, now: float) -> list:
        """The agent's timers, held records and my state: nothing is done when nothing is due (:meth:`idle`)."""
        if self.idle(now):
            if self.check_idle:
                return self._checked_tick(now)
            return []
        return self._tick(now)

    def _tick(self, now: float) -> list:
        self._changed = False
        if self._started is None:
            self._started = now
        out = self.agent.on_tick(now) + self._pending_tick(now)
        for ev in self.agent.pop_events():
            self.events.append(ev)
            who = "+".join(f"R{r}" for r in ev.robots)
            if ev.what == DONE:
                out += self.table.mark(ev.task, T_DONE, tuple(ev.robots))
                self.notices.append(Notice(f"task {_tid(ev.task)} done by {who}", 5))
            elif ev.what == AWARDED:
                self.notices.append(Notice(f"task {_tid(ev.task)} awarded to {who}", 6))
            else:
                self.notices.append(Notice(f"task {_tid(ev.task)} {ev.what} by {who}"
                                           + (f": {ev.detail}" if ev.detail else ""), 4))
        return out + self._state_now(now)

    check_idle = False          # tests: an idle tick is run anyway, and must send nothing and change nothing

    def idle(self, now: float) -> bool:
        """The tick at ``now`` would send nothing and change nothing: my state not due again and the same as I
        sent last (it is when no input came since the last tick), no held record, and an agent that says its own
        tick is quiet.  Agents without ``quiet`` tick every time."""
        if (self._quiet is None or self._started is None or now >= self._next_state or self._pending
                or not self._quiet(now)):
            return False
        if self._changed:
            held = self.held()
            if (self._state(held), held, self.table.digest) != self._last_state:
                return False
            self._changed = False
        return True

    def _checked_tick(self, now: float) -> list:
        before = _fingerprint(self)
        out = self._tick(now)
        if out or _fingerprint(self) != before:
            raise AssertionError(f"robot {self.robot_id}: a tick at {now!r} judged idle did something: {out}")
        return out

    @property
    def state(self) -> int:
        return self._state(self.held())

    def _state(self, held: tuple[int, ...]) -> int:
        """The state, given what the agent holds (:meth:`held`: the agent's commitments are built on each read)."""
        if not self.armed:
            return DISARMED
        if not self.localized:
            return LOCALIZING
        if getattr(self.agent, "allocating", False):
            return ALLOCATING
        return EXECUTING if held else IDLE

    def held(self) -> tuple[int, ...]:
        return tuple(c.task_id for c in self.agent.commitments)[:MAX_HELD]

    def robot_state(self, dest: int = BROADCAST) -> RobotState:
        x, y = self.pose if self.pose is not None else (math.nan, math.nan)
        return RobotState(self.robot_id, dest, self.state, self.held(), float(x), float(y), len(self.table.entries),
                          self.table.digest)

    def _state_now(self, now: float) -> list:
        """My state to the peers: at once when it changes, else every ``state_period``."""
        held = self.held()
        key = (self._state(held), held, self.table.digest)
        if key == self._last_state and now < self._next_state:
            return []
        self._last_state = key
        self._next_state = now + self.state_period
        return [self.robot_state()]

    def pop_notices(self) -> list[Notice]:
        out, self.notices = self.notices, []
        return out


def _fingerprint(node: FleetNode) -> str:
    """The node's and its agent's state, as text (the agent's clock and logger aside): what an idle tick must
    leave as it found it."""
    return repr(_plain((node.agent, node._last_state, node._next_state, node._started, node.events, node.notices,
                        node.table.digest), set()))


def _plain(v, seen: set):
    """``v`` as nested tuples of plain values, objects by their attributes (each object once: leaders point back
    at their agent)."""
    if isinstance(v, (str, bytes, int, float, bool, type(None))):
        return v
    if id(v) in seen:
        return "<seen>"
    seen.add(id(v))
    if isinstance(v, dict):
        return tuple((repr(k), _plain(x, seen)) for k, x in v.items())
    if isinstance(v, (list, tuple, set, frozenset)) or type(v).__name__ == "deque":
        items = sorted(v, key=repr) if isinstance(v, (set, frozenset)) else v
        return (type(v).__name__,) + tuple(_plain(x, seen) for x in items)
    if hasattr(v, "__dict__"):
        return (type(v).__name__,) + tuple((k, _plain(x, seen)) for k, x in vars(v).items()
                                           if k not in ("now", "log", "estimator"))
    return repr(v)


def _tid(task_id: int) -> str:
    """A fleet task id as people read it: origin robot and number, e.g. 1.3."""
    return f"{task_id >> 16}.{task_id & 0xFFFF}"
