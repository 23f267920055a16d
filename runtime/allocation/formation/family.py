"""The formation methods (paper 002's BS and RTMA, and the epsilon-scaling auction) as daemon agents.

Each method's solver (:class:`~runtime.allocation.formation.bs.BSAgent`, ``RTMAAgent``,
``EpsAuctionAgent``) solves one assignment problem: a fixed task set among a fixed set of robots, one
task per robot, started by one robot.  Tasks reach a fleet at any time, though, and robots finish them,
get lost and are disarmed.  :class:`FormationAgent` runs the solver in **rounds**:

* A round allocates the open tasks no robot holds (at most ``MAX_ROUND``, or one per free robot if there are more,
  lowest ids first) among the robots that are free (armed, localized, holding no task).  The lowest-id free robot
  starts it with a ``RoundStart`` naming the tasks and the robots (in parts if a list is longer than one frame
  holds; a robot acts on it once it has every part), then runs its solver's ``start``; a free robot named
  in it joins with a solver of its own, one that is not free answers ``RoundLeave`` and its peers in the
  round treat it as lost there.  A free robot whose table lacks one of the round's tasks (its record was lost
  on the way; the state digests bring it within a second or two) waits for it, quiet and starting no round of
  its own, up to a bid timeout, then joins, or answers ``RoundLeave``: leaving at once would have it start a
  round for the tasks it knows and split the problem, each robot taking its own best instead of the fleet's.
  For the same reason the starter sends its ``RoundStart`` again, while the round negotiates, to the robots
  that have not spoken in it (:meth:`FormationAgent._restart_silent`).
  If the lowest free robot has not started a round within ``start_wait`` seconds, the next one does, unless a
  lower robot may have a round going that it never heard of (:meth:`FormationAgent._held_off`).  Inside
  a round, task ids are indices into the ``RoundStart``'s list and every message carries the round id, so
  rounds never mix.
* A robot's commitment is its solver's current assignment (it follows re-auctions inside the round).
  It keeps its solver, and so keeps answering as the holder, while it works on the task; when the task
  is done or withdrawn it drops the solver and is free again.  A robot the round left without a task
  drops out once the round has been quiet for ``linger`` seconds and no robot of it says it is still allocating.
* Robots tell each other what they hold (``RobotState``, every second and on each change).  Tasks a
  live robot holds are not offered again; a lost robot's tasks are.  A lossy link makes a live robot look
  lost now and then; BS and RTMA re-auction its task then, and are told what the live robots hold by their
  states, so a task resold since, or held by its robot in another round, is not re-auctioned (see
  :meth:`~runtime.allocation.formation.bs.BSAgent._open` for the robot that is not lost after all).  If two
  robots end up holding the same task (rounds that overlapped), the lower id keeps it and the other lets it go.
* A robot asked something in a round it is not in (a message addressed to it, a ``Status`` or an ``Announce``)
  answers ``RoundLeave`` for it, at most once a bid timeout: the asker counts it as one of the round's live robots
  (its ``RoundLeave`` was lost, or the ``RoundStart`` never reached it) and would wait for it for ever; a robot
  invited to the round and waiting for its table stays quiet (the round's solvers ask again once it is in).
* A round that got no task taken is not repeated by its initiator with the same tasks and free robots
  until a back-off (doubling, at most 30 s) has passed: a task nobody can reach is not auctioned in a
  tight loop (the robot an operator hands it to refuses a task it cannot reach in the first place).

With every robot free and the tasks handed in at once (a formation), round 1 is exactly the solver's
problem: same robots, same tasks in the same order, started by the lowest id, so the daemons give the
same result as the in-process solver for the same costs.

What a round message says is checked against the round before its solver sees it; what does not fit is
dropped and counted in :attr:`FormationAgent.dropped`: a sender that is not one of the round's robots, a task
index beyond the round's task list (the epsilon auction's "no task" slots excepted), a winner or price holder
that is not in the round, a task set (``TaskInfo``, ``Announce``) that contradicts the round's tasks in the
fleet table (size or position), a ``RoundStart`` whose round id is not its sender's or that names robots
outside the fleet.  A round that stays unconverged with nothing heard from its peers for ``SILENT_ROUNDS``
bid timeouts (a forged ``RoundStart``, or an initiator that died at once) is left, the silence counted from when
it last went from converged to not (a settled round is quiet: there is nothing to say); a round of one robot,
which has no peers to hear, is not (its solver ends it: left that way, BS went round in circles).  Values within all of
these from a sender whose id is forged cannot be told from genuine ones without signing (the fleet's default):
a forged ``Price`` from a round member at a plausible price, an ``Award`` at the winner's own bid.  For two
robots that end up holding one task, whatever the cause, the lower id keeps it once both have settled.
"""
from __future__ import annotations

import dataclasses
import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Sequence

from runtime.allocation.agent import AWARDED, DONE, RELEASED, AgentContext, Method, TaskEvent
from runtime.allocation.formation.bs import BSAgent
from runtime.allocation.formation.eps_auction import EpsAuctionAgent
from runtime.allocation.formation.assignment import MAX_TASKS, NO_TASK
from runtime.allocation.formation.messages import (AGENT_MESSAGES, MAX_PARTS, MAX_ROUND, ROUND_MESSAGES, Announce,
                                                   Award, Price, RoundLeave, RoundStart, Status, TaskInfo,
                                                   join_round, split_round)
from runtime.allocation.formation.options import AuctionOptions, BSOptions, RTMAOptions
from runtime.allocation.formation.rtma import RTMAAgent
from runtime.messages import BROADCAST, ALLOCATING, EXECUTING, IDLE, RobotState, why_invalid
from runtime.log import get_logger
from runtime.tasks import DONE as P_DONE, FAILED as P_FAILED, Commitment, Progress, Task

HOLD_OFF = 3                # start waits a free robot holds off for a lower robot silent or allocating
MAX_BACKOFF = 30.0
SILENT_ROUNDS = 10          # bid timeouts an unconverged round may go without a message from a peer
MAX_PENDING = 8             # rounds announced in parts whose other parts a robot waits for at once
SAME_POSITION = 1e-3        # m: a task position on the wire (float32) and in the table agree within this


@dataclass
class Round:
    id: int
    tasks: tuple[int, ...]             # fleet task ids; a task's index here is its id inside the round
    robots: tuple[int, ...]
    solver: object | None = None       # None: I only know of it
    last_heard: float = 0.0            # last message of this round in or out
    last_in: float = 0.0               # last message of this round from a peer (or when I joined it)
    busy_since: float | None = None    # when its solver last went from converged to not (None: converged)
    heard: set = field(default_factory=set)    # robots that have spoken in it (a RoundLeave is not speaking)
    start_sent: float = 0.0            # when I (its starter) last sent its RoundStart


@dataclass
class PeerView:
    state: int = IDLE                  # never heard: taken to be free, so a fleet's first round has everyone
    tasks: tuple[int, ...] = ()
    at: float | None = None            # when its last state came (None: never)


@dataclass
class _Backoff:
    key: tuple = ()
    until: float = -math.inf
    wait: float = 1.0


class FormationAgent:
    """One robot's formation-family agent (see the module docstring)."""

    def __init__(self, ctx: AgentContext, solver: type, solver_options: dict):
        self.robot_id = int(ctx.robot_id)
        self.peers = tuple(sorted(set(ctx.peers) - {self.robot_id}))
        self.estimator = ctx.estimator
        self.options = ctx.options
        self.solver_cls = solver
        self.solver_options = solver_options
        self.tasks: dict[int, Task] = {}              # open fleet tasks I know of
        self.lost: set[int] = set()
        self.view: dict[int, PeerView] = {p: PeerView() for p in self.peers}
        self.rounds: dict[int, Round] = {}            # rounds I take part in
        self.available = True
        self.localized = True
        self._count = 0
        self._free_since: float | None = None
        self._held: int | None = None                 # the task of my last commitment
        self._announced: int | None = None            # the last task I reported awarded
        self._events: list[TaskEvent] = []
        self._backoff = _Backoff()
        self._now = 0.0
        self.dropped: Counter = Counter()             # round messages that did not fit their round, by reason
        self._clash: dict[int, int | None] = {}       # peer -> my task its last state named too (same round)
        self._not_in_told: dict[int, float] = {}      # round I am not in -> when I last said so
        self._not_in_asked: dict[int, float] = {}     # round I am not in -> when it first asked me something
        self._invited: dict[int, tuple[RoundStart, float]] = {}   # round naming tasks my table lacks -> (it, when)
        self._joined: dict[int, float] = {}           # peer -> when it joined my roster at run time
        self._parts: dict[int, tuple[float, dict[int, RoundStart]]] = {}   # round announced in parts -> (since, parts)
        self.log = get_logger(f"alloc.{getattr(self.options, 'method', 'formation')}", self.robot_id)

    # ------------------------------------------------------------------ what the daemon reads
    @property
    def commitments(self) -> tuple[Commitment, ...]:
        task = self._assigned()
        return () if task is None else (Commitment(self.tasks[task]),)

    @property
    def converged(self) -> bool:
        return all(r.solver.converged for r in self.rounds.values())

    @property
    def allocating(self) -> bool:
        return any(not r.solver.converged for r in self.rounds.values())

    def pop_events(self) -> list[TaskEvent]:
        out, self._events = self._events, []
        return out

    def _assigned(self) -> int | None:
        """The fleet task my solvers give me, if it is still open (my newest round first)."""
        for r in sorted(self.rounds.values(), key=lambda r: -r.id):
            task = self._local(r)
            if task is not None and task in self.tasks:
                return task
        return None

    @staticmethod
    def _local(r: Round) -> int | None:
        """The fleet task round ``r``'s solver gives me, or None."""
        local = r.solver.assignment
        return r.tasks[local] if local is not None and 0 <= local < len(r.tasks) else None

    @property
    def free(self) -> bool:
        return self.available and self.localized and self._assigned() is None and not self.allocating

    # ------------------------------------------------------------------ inputs
    def add_tasks(self, tasks: Sequence[Task], now: float) -> list:
        for t in tasks:
            self.tasks[t.id] = t
        return []

    def withdraw_tasks(self, task_ids: Sequence[int], now: float) -> list:
        for tid in task_ids:
            self.tasks.pop(tid, None)
        return self._settle(now)

    def set_available(self, available: bool, now: float) -> list:
        """Disarmed: leave every round (peers treat me as lost there, so my task is auctioned again)."""
        self.available = bool(available)
        if available:
            return []
        out = []
        for r in list(self.rounds.values()):
            out += self._leave(r, now, tell=True)
        return out

    def set_localized(self, localized: bool) -> None:
        self.localized = bool(localized)

    def on_peer_lost(self, robot_id: int, now: float) -> list:
        self._now = now
        self.lost.add(robot_id)
        self.view.pop(robot_id, None)
        out = []
        for r in list(self.rounds.values()):
            if robot_id in r.robots:
                out += self._from(r, r.solver.on_peer_lost(robot_id, now), now)
        return out + self._settle(now)

    def on_peer_joined(self, robot_id: int, now: float) -> list:
        """A robot joined the fleet: a peer from now on.  Rounds going on keep their robots (a solver's problem is
        fixed); the next round a free robot starts includes it when its state says it is free.  For ``HOLD_OFF`` start
        waits, its saying it is allocating holds me off starting a round whatever its id (:meth:`_held_off`): a robot
        that joins a running fleet (all its peers join its roster) must not split a round it never heard start."""
        self._now = now
        if robot_id != self.robot_id and robot_id not in self.peers:
            self.peers = tuple(sorted({*self.peers, int(robot_id)}))
            self._joined[int(robot_id)] = now
        self.lost.discard(robot_id)
        self.view.setdefault(robot_id, PeerView())
        return []

    def on_progress(self, p: Progress, now: float) -> list:
        self._now = now
        if p.event == P_DONE and p.task in self.tasks:
            self._events.append(TaskEvent(p.task, DONE, (self.robot_id,)))
            del self.tasks[p.task]
            return self._settle(now)
        if p.event == P_FAILED:
            self.log.warning("task %d failed: %s", p.task, p.detail)
        return []

    def on_message(self, msg, now: float) -> list:
        self._now = now
        sender = getattr(msg, "sender", None)
        if sender in self.lost:
            self.lost.discard(sender)             # heard again
            self.view.setdefault(sender, PeerView())
        for r in self.rounds.values():
            if sender in r.robots:
                r.solver.heard(sender, now)       # a solver may wait to be sure a peer is lost (the auction does)
        if isinstance(msg, RobotState):
            return self._on_state(msg, now)
        if isinstance(msg, RoundStart):
            return self._on_round_start(msg, now)
        if isinstance(msg, RoundLeave):
            r = self.rounds.get(msg.round)
            if r is None or msg.sender not in r.robots:
                return []
            r.last_heard = r.last_in = now
            return self._from(r, r.solver.on_peer_lost(msg.sender, now), now) + self._settle(now)
        rid = getattr(msg, "round", None)
        if rid is None:
            return []
        r = self.rounds.get(rid)
        if r is None:
            return self._not_in(rid, msg, now)
        why = self._outside(r, msg)
        if why is not None:
            self.dropped[why] += 1
            self.log.debug("dropped %s from robot %s: %s", type(msg).__name__, msg.sender, why)
            return []
        r.last_heard = r.last_in = now
        r.heard.add(msg.sender)
        return self._from(r, r.solver.on_message(msg, now), now) + self._settle(now)

    def _not_in(self, rid: int, msg, now: float) -> list:
        """A message of a round I am not in (never joined, or left).  None of my business, unless it asks me
        something (addressed to me; a ``Status``, the epsilon auction asking for entries it misses; an ``Announce``,
        BS and RTMA asking for bids): then its sender may count me as one of the round's live robots (my
        ``RoundLeave`` was lost, or I never heard its ``RoundStart``) and wait for me for ever, at the epsilon
        auction's barrier or for my bid.  I say I am not in it, ``RoundLeave`` to all, at most once per round and
        bid timeout, and not when first asked: its first questions go out with its ``RoundStart`` and may overtake
        it (the asker asks again after a bid timeout)."""
        if rid in self._invited or (
                getattr(msg, "dest", BROADCAST) != self.robot_id and not isinstance(msg, (Status, Announce))):
            return []                # no question; or invited, waiting for my table: it asks again once I am in
        horizon = SILENT_ROUNDS * self.options.bid_timeout
        self._not_in_asked = {k: t for k, t in self._not_in_asked.items() if now - t < horizon}
        if now - self._not_in_asked.setdefault(rid, now) < self.options.bid_timeout / 2:
            return []
        if now - self._not_in_told.get(rid, -math.inf) < self.options.bid_timeout:
            return []
        self._not_in_told = {k: t for k, t in self._not_in_told.items() if now - t < horizon}
        self._not_in_told[rid] = now
        self.dropped["asked about a round I am not in"] += 1
        return [RoundLeave(self.robot_id, BROADCAST, rid)]

    def _outside(self, r: Round, msg) -> str | None:
        """Why ``msg`` cannot be a message of round ``r``, or None."""
        if msg.sender not in r.robots:
            return "sender not in the round"
        n = len(r.tasks)
        task = getattr(msg, "task", None)
        if task is not None and not (task < n or (isinstance(msg, Status) and task == NO_TASK)
                                     or (isinstance(msg, Price) and task >= MAX_TASKS - len(r.robots))):
            return "task not in the round"
        robot = msg.winner if isinstance(msg, Award) else msg.holder if isinstance(msg, Price) else None
        if robot is not None and robot not in r.robots:
            return "robot not in the round"
        if isinstance(msg, (TaskInfo, Announce)):
            if isinstance(msg, TaskInfo) and msg.n_tasks != n:
                return "contradicts the round's task set"
            fleet = self.tasks.get(r.tasks[task])
            if fleet is not None and math.dist(fleet.position, (msg.x, msg.y)) > SAME_POSITION:
                return "contradicts the round's task set"
        return None

    def on_tick(self, now: float) -> list:
        self._now = now
        out = self._answer_invitations(now) + self._restart_silent(now)
        for r in list(self.rounds.values()):
            out += self._from(r, r.solver.on_tick(now), now)
        out += self._settle(now)
        out += self._maybe_start(now)
        return out

    # ------------------------------------------------------------------ rounds
    def _on_state(self, m: RobotState, now: float) -> list:
        """A peer's state.  If it holds my task and neither of us is still allocating, the lower id keeps the
        task: at once when it comes from another round (rounds that overlapped); inside one round only when two
        states in a row say so, since one may lag a resale there (two robots settled on one task in one round
        is no outcome of the protocol: a lost or forged message)."""
        v = self.view.setdefault(m.sender, PeerView())
        v.state, v.tasks, v.at = m.state, tuple(m.tasks), now
        mine = self._assigned()
        twice, self._clash[m.sender] = self._clash.get(m.sender) == mine, None
        if mine is None or mine not in v.tasks or m.sender > self.robot_id or self.allocating or m.state != EXECUTING:
            return []
        r = next((r for r in self.rounds.values() if self._local(r) == mine), None)
        if r is None:
            return []
        if m.sender in r.robots and not twice:
            self._clash[m.sender] = mine
            return []
        self.log.warning("robot %d holds task %d too: it keeps it (lower id), I let it go", m.sender, mine)
        self._events.append(TaskEvent(mine, RELEASED, (self.robot_id,), f"robot {m.sender} holds it"))
        return self._leave(r, now, tell=False) + self._settle(now)

    def _on_round_start(self, m: RoundStart, now: float) -> list:
        if m.last:
            m = self._whole(m, now)
            if m is None:
                return []
        if self.robot_id not in m.robots or m.round in self.rounds:
            return []
        if m.round >> 16 != m.sender or not set(m.robots) <= {self.robot_id, *self.peers}:
            self.dropped["round start outside the protocol"] += 1
            return []
        if not self.free:
            return [RoundLeave(self.robot_id, BROADCAST, m.round)]
        if any(t not in self.tasks for t in m.tasks):      # my table is behind: wait for it (module docstring)
            self._invited.setdefault(m.round, (m, now))
            return []
        return self._join(m, now)

    def _whole(self, m: RoundStart, now: float) -> RoundStart | None:
        """The round part ``m`` belongs to once I have all its parts, else None (I keep the part).  A lost part comes
        again with the starter's re-sends (:meth:`_restart_silent`: every part, to a robot not heard in the round);
        parts of at most ``MAX_PENDING`` rounds are kept, none older than the silence that ends a round, and parts
        that contradict each other (their ``last``) are replaced by the newest."""
        if m.round in self.rounds or m.round >> 16 != m.sender:
            return None
        horizon = SILENT_ROUNDS * self.options.bid_timeout
        self._parts = {k: v for k, v in self._parts.items() if now - v[0] < horizon}
        since, parts = self._parts.get(m.round, (now, {}))
        if any(p.last != m.last for p in parts.values()):
            self.dropped["round start parts that contradict"] += 1
            since, parts = now, {}
        parts[m.part] = m
        self._parts[m.round] = (since, parts)
        while len(self._parts) > MAX_PENDING:
            del self._parts[min(self._parts, key=lambda k: self._parts[k][0])]
        if len(parts) <= m.last:
            return None
        del self._parts[m.round]
        whole = join_round([parts[k] for k in range(m.last + 1)])
        if why_invalid(whole):
            self.dropped["round start outside the protocol"] += 1
            return None
        return whole

    def _restart_silent(self, now: float) -> list:
        """My rounds still negotiating: their ``RoundStart`` again, each bid timeout, to the robots named in them that
        have not spoken in them.  One lost ``RoundStart`` keeps a robot out (ten robots at 10 % loss: one of nine
        misses it more often than not); it answers the round's questions "not in it", starts a round of its own
        after ``start_wait``, and the two split the problem.  Still free, it joins on a later one (its peers hear
        it again).  Robots that are busy answer ``RoundLeave`` again, at most once a bid timeout."""
        out = []
        for r in self.rounds.values():
            if r.id >> 16 != self.robot_id or r.solver.converged or now - r.start_sent < self.options.bid_timeout:
                continue
            r.start_sent = now
            out += [m for p in r.robots if p != self.robot_id and p not in r.heard
                    for m in split_round(self.robot_id, p, r.id, r.tasks, r.robots)]
        return out

    def _answer_invitations(self, now: float) -> list:
        """Join the rounds I was invited to once my table has their tasks; leave them after a bid timeout."""
        out = []
        for rid, (m, since) in list(self._invited.items()):
            if not self.free or now - since >= self.options.bid_timeout:
                del self._invited[rid]
                out.append(RoundLeave(self.robot_id, BROADCAST, rid))
            elif all(t in self.tasks for t in m.tasks):
                del self._invited[rid]
                out += self._join(m, now)
        return out

    def _join(self, m: RoundStart, now: float) -> list:
        r = Round(m.round, tuple(m.tasks), tuple(m.robots), last_heard=now, last_in=now)
        r.solver = self._solver(r)
        self.rounds[r.id] = r
        self.log.info("joined round %s: %d tasks, robots %s", _rid(r.id), len(r.tasks), list(r.robots))
        return []

    def _solver(self, r: Round):
        tasks = [self.tasks[t] for t in r.tasks]

        def cost(local: int) -> float:          # one estimate batch for the round's tasks (cached by the estimator)
            return self.estimator.estimates(tasks)[local].cost

        def held_elsewhere(local: int) -> bool:  # a live peer's last state names it, or another round gives it me
            task = r.tasks[local]
            return task == self._assigned() or any(task in v.tasks for p, v in self.view.items() if p not in self.lost)

        peers = [p for p in r.robots if p != self.robot_id]
        solver = self.solver_cls(self.robot_id, peers, cost, **self.solver_options)
        if hasattr(solver, "held_elsewhere"):    # a solver that re-auctions a lost robot's task (BS, RTMA)
            solver.held_elsewhere = held_elsewhere
        return solver

    def _candidates(self) -> tuple[list[int], list[int]]:
        """(open tasks no live robot holds, free robots I know of with me first), lowest ids first."""
        held = {t for p, v in self.view.items() if p not in self.lost for t in v.tasks}
        in_rounds = {t for r in self.rounds.values() for t in r.tasks}
        robots = [self.robot_id] + [p for p in self.peers if p not in self.lost and self._peer_free(p)]
        tasks = [t for t in sorted(self.tasks) if t not in held and t not in in_rounds]
        return tasks[:max(MAX_ROUND, min(len(robots), MAX_PARTS * MAX_ROUND))], sorted(robots)

    def _held_off(self, lower: list[int], now: float) -> bool:
        """A lower robot may have a round going that names me though its ``RoundStart`` never reached me (a loss
        spell): one that I take to be free but have not heard a state from within ``start_wait`` (never, or its
        states stopped coming), or one whose last state, that recent, says it is allocating.  I wait for it (the
        starter sends its ``RoundStart`` again to a robot not heard in its round), up to ``HOLD_OFF`` start waits
        from when I was free, or until it is declared lost, instead of starting a round of my own and splitting
        the problem: each robot would take its own best, not the fleet's."""
        for p, v in self.view.items():
            if p in self.lost:
                continue
            recent = v.at is not None and now - v.at <= self.options.start_wait
            if p > self.robot_id:
                # a robot that joined my roster lately: its round may have started before one of us was there (a
                # robot joining a running fleet), so its allocating holds me off too, whatever its id
                if recent and v.state == ALLOCATING and self._just_joined(p, now):
                    return True
                continue
            if (p in lower and not recent) or (recent and v.state == ALLOCATING):
                return True
        return False

    def _just_joined(self, p: int, now: float) -> bool:
        return now - self._joined.get(p, -math.inf) <= HOLD_OFF * self.options.start_wait

    def _peer_free(self, p: int) -> bool:
        v = self.view.get(p)
        return v is not None and v.state == IDLE and not v.tasks

    def _maybe_start(self, now: float) -> list:
        if not self.free or self._invited:
            self._free_since = None
            return []
        tasks, robots = self._candidates()
        if not tasks:
            self._free_since = None
            return []
        if self._free_since is None:
            self._free_since = now
        lower = [p for p in robots if p < self.robot_id]
        if lower and now - self._free_since < self.options.start_wait:
            return []
        if now - self._free_since < HOLD_OFF * self.options.start_wait and self._held_off(lower, now):
            return []
        key = (tuple(tasks), tuple(robots))
        if key == self._backoff.key and now < self._backoff.until:
            return []
        self._count = self._count % 0xFFFF + 1
        r = Round(self.robot_id << 16 | self._count, tuple(tasks), tuple(robots), last_heard=now, last_in=now,
                  start_sent=now)
        r.solver = self._solver(r)
        self.rounds[r.id] = r
        if key == self._backoff.key:
            self._backoff.wait = min(2 * self._backoff.wait, MAX_BACKOFF)
        else:
            self._backoff = _Backoff(key, wait=1.0)
        self._backoff.until = now + self._backoff.wait
        self.log.info("starting round %s: tasks %s, robots %s", _rid(r.id), list(tasks), list(robots))
        out = split_round(self.robot_id, BROADCAST, r.id, r.tasks, r.robots)
        positions = {i: self.tasks[t].position for i, t in enumerate(r.tasks)}
        out += self._from(r, r.solver.start(positions, now), now)
        out += self._from(r, r.solver.on_tick(now), now)
        return out

    def _from(self, r: Round, msgs: list, now: float) -> list:
        """Solver output, stamped with its round."""
        if msgs:
            r.last_heard = now
        return [dataclasses.replace(m, round=r.id) for m in msgs]

    def _negotiating(self, r: Round) -> bool:
        """Some live robot of round ``r`` says it is still allocating (its state): a resale there may yet be offered to
        me, a robot without a task.  A quiet spell for me is not the round's end: leaving then, I would start a round
        of my own for its open tasks while it still trades them."""
        return any(v.state == ALLOCATING for p, v in self.view.items() if p in r.robots and p not in self.lost)

    def _leave(self, r: Round, now: float, tell: bool) -> list:
        self.rounds.pop(r.id, None)
        self.log.info("leaving round %s", _rid(r.id))
        return [RoundLeave(self.robot_id, BROADCAST, r.id)] if tell else []

    def _settle(self, now: float) -> list:
        """Drop rounds that are over for me; report a new commitment."""
        out = []
        for r in list(self.rounds.values()):
            task = self._local(r)
            if task is not None and task not in self.tasks:
                out += self._leave(r, now, tell=False)          # done or withdrawn: I am free
            elif (task is None and r.solver.converged and now - r.last_heard >= self.options.linger
                  and not self._negotiating(r)):
                out += self._leave(r, now, tell=False)          # the round left me without a task
            elif r.solver.converged:
                r.busy_since = None
            elif r.busy_since is None:
                r.busy_since = now          # a settled round is quiet: its silence counts from here
            elif (len(r.robots) > 1            # alone, there is none to hear
                  and now - max(r.last_in, r.busy_since) >= SILENT_ROUNDS * self.options.bid_timeout):
                self.log.warning("round %s: nothing heard for %.1f s and not converged: leaving it", _rid(r.id),
                                 now - max(r.last_in, r.busy_since))
                self.dropped["silent round left"] += 1
                out += self._leave(r, now, tell=True)
        held = self._assigned()
        if held != self._held:
            if held is not None:
                self._backoff = _Backoff()
            self._held = held
        if held is not None and held != self._announced and not self.allocating:
            self._announced = held                   # told once the round has settled, not at every bid
            self._events.append(TaskEvent(held, AWARDED, (self.robot_id,)))
        return out


def _rid(round_id: int) -> str:
    return f"{round_id >> 16}.{round_id & 0xFFFF}"


def _make(solver: type, extra: tuple[str, ...]):
    def make(ctx: AgentContext) -> FormationAgent:
        o = ctx.options
        opts = {"bid_timeout": o.bid_timeout, **{k: getattr(o, k) for k in extra}}
        return FormationAgent(ctx, solver, opts)
    return make


_XML = str(__import__("pathlib").Path(__file__).with_name("formation.xml"))
_MSGS = AGENT_MESSAGES + ROUND_MESSAGES

BS = Method("bs", "paper 002 basic market algorithm: auction, resell the dearer of two tasks", BSOptions,
            _make(BSAgent, ("max_retries",)), ("goto",), _MSGS, _XML, BSAgent)
RTMA = Method("rtma", "paper 002 RTMA: BS with bids relative to each robot's mean cost", RTMAOptions,
              _make(RTMAAgent, ("max_retries",)), ("goto",), _MSGS, _XML, RTMAAgent)
AUCTION = Method("auction", "epsilon-scaling auction (Bertsekas): optimal assignment, the default", AuctionOptions,
                 _make(EpsAuctionAgent, ("cost_unit", "theta")), ("goto",), _MSGS, _XML, EpsAuctionAgent)
