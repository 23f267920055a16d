"""Bertsekas' auction algorithm with epsilon-scaling, as a distributed sans-IO agent (the default).

Each robot keeps a price table: per task the highest price heard and the robot that bid it.  A robot
that holds no task bids for its best task j (value v_j = -cost_j - price_j) by raising its price to
price_j + (v_j - w) + eps, w the second-best value, and broadcasts ``Price(task, holder=me, price,
phase)``.  A table entry is replaced only by a higher (price, -holder): highest bid wins, equal prices
go to the lowest id, stale prices lose - so every table converges to the same entries whatever the
order, loss or duplication of messages.  A robot that sees its task taken at a higher price bids again.

Epsilon-scaling: eps runs down one ladder the whole fleet shares, eps_k = ``eps_final`` * ``theta``**k
with ``eps_final`` = ``cost_unit`` / (n + 1), from the first rung at or above (my largest cost) / ``theta``
down to k = 0.  ``Price.phase`` carries the sender's k, the rungs it has left.  A robot steps down a rung
when its table shows every live robot holding a task and nothing has changed for ``bid_timeout / 4``
(or nothing at all for twice that: its table may be stale), and only when every live peer has told it
(by any ``Price`` it sent) that it stands on the same rung or a lower one; it then tells everyone its
new rung with its entry, and keeps its task only if the task is still within the new eps of its best
(eps-complementary slackness), else it bids again.  The rung barrier keeps the fleet within one rung:
a robot on a fine eps never fights a price war over a gap that a robot on a coarse eps left, which
without it takes (gap / eps) bids and, with 50 ms links, minutes.  A robot waiting at the barrier
for ``bid_timeout`` asks for the entries it misses (a ``Status`` broadcast, as below).  At the end
every robot is within eps_final of its best task at the final prices, so the total cost is within
n * eps_final of the optimum: exact for costs that are multiples of ``cost_unit``.  ``theta`` = 8
(fewer rungs, so fewer rung announcements) beat 4 in messages and time at 10-200 ms delays
(``benchmarks/auction_messages.py --delay``).

Loss: a robot whose table is incomplete and unchanged for ``bid_timeout`` (or that still misses
part of the task set ``bid_timeout`` after it first heard from the fleet) broadcasts
``Status(auction=0, task=held or NO_TASK, converged=False)`` (no auction here: ``auction`` is always 0);
every holder rebroadcasts its own entry and the initial auctioneer the task set if the robot holds
nothing (each at most once per ``bid_timeout``); once the initial auctioneer is lost, every robot that
knows the whole set serves it instead (the barrier would otherwise hold the fleet on a coarse eps).
A robot that outbids another and hears nothing from it within ``bid_timeout / 4`` sends it the new
entry directly (up to 3 times); a holder answers any stale ``Price`` for its task with the current
entry; every holder rebroadcasts its entry every ``keepalive`` seconds.

Who may name a holder: a ``Price`` names its sender as the holder, except the one answer that hands a freed
task back to a robot that still claims it (sent to that robot, naming it, for the task it holds); any other is
dropped and counted.
A ``Price`` from a robot with a forged id (naming itself) at a plausible price cannot be told from its own bid
without signing: with a price far above what the others would pay it can hold the auction in a price war.  Task positions and N_T come
from ``TaskInfo`` broadcast by ``start()``.

More robots than tasks: each robot adds one zero-cost "no task" slot per surplus robot (the standard
reduction to a square problem); a robot on such a slot reports ``assignment`` None.  A lost robot's
task is freed at its price (once the robot has not answered ``LOST_PROBES`` direct questions, see
:meth:`EpsAuctionAgent.on_peer_lost`) and stays open unless a robot now prefers it: the survivors keep a valid
assignment, but with fewer robots than tasks it is not guaranteed optimal for the smaller fleet.
"""
from __future__ import annotations

import math
from collections import Counter
from typing import Callable, Mapping, Sequence

from runtime.allocation.formation.assignment import LOST_PROBES, MAX_TASKS, NO_TASK, TaskBook
from runtime.allocation.formation.messages import MAX_VALUE, Price, Status, TaskInfo, addressed_to
from runtime.log import get_logger
from runtime.messages import BROADCAST

INF = math.inf
NO_RUNG = 0xFFFF          # Price.phase before the sender knows the task set


class EpsAuctionAgent:
    """One robot's auction-algorithm bidder.  See the module docstring for the protocol."""

    method = "auction"

    def __init__(self, robot_id: int, peers: Sequence[int], cost: Callable[[int], float], *,
                 bid_timeout: float = 1.0, quiet: float | None = None, cost_unit: float = 0.01,
                 theta: float = 8.0, eps_final: float | None = None, keepalive: float | None = None):
        self.robot_id = int(robot_id)
        self.peers = sorted({int(p) for p in peers} - {self.robot_id})
        self.alive = set(self.peers)
        self.bid_timeout = float(bid_timeout)
        self.quiet = self.bid_timeout if quiet is None else float(quiet)
        self.settle = self.bid_timeout / 4
        self.keepalive = 10 * self.bid_timeout if keepalive is None else float(keepalive)
        self.cost_unit = float(cost_unit)
        self.theta = float(theta)
        self.eps_final = eps_final
        self.book = TaskBook(cost)
        self.price: dict[int, float] = {}
        self.holder: dict[int, int] = {}           # task -> robot id, 0 = nobody
        self.held: int | None = None
        self.phase = 0
        self.schedule: list[float] = []            # eps per phase, empty until the task set is known
        self.bids = 0                              # bids this robot made
        self.dropped: Counter = Counter()
        self.sent = 0
        self._holders: Counter = Counter()         # robot -> number of tasks it holds in my table
        self._initiator = False
        self._task_source: int | None = None       # the robot whose TaskInfo taught me the task set
        self._active = False
        self._active_since = INF
        self._now = 0.0
        self._last_change = -INF
        self._last_own = -INF                      # last time my entry went out
        self._last_solicit = -INF
        self._served: dict[str, float] = {}
        self._notices: dict[int, list] = {}        # displaced robot -> [task, deadline, tries]
        self._dummies: set[int] = set()            # "no task" slots when robots outnumber tasks
        self._peer_rung: dict[int, int] = {}       # robot -> lowest rung it has reported
        self._suspects: dict[int, list] = {}       # peer declared lost, holding a task -> [last asked, times asked]
        self.log = get_logger("alloc.auction", self.robot_id)

    @staticmethod
    def options_for(costs) -> dict:
        """``cost_unit`` for a cost matrix solved in-process: 1 for integer costs (eps_final < 1/n is then
        exact), else 1 ppm of the largest cost."""
        import numpy as np

        c = np.asarray(costs, dtype=float)
        if np.all(c == np.round(c)):
            return {"cost_unit": 1.0}
        return {"cost_unit": 1e-6 * float(c.max())} if c.max() > 0 else {}

    # ------------------------------------------------------------------ agent interface
    @property
    def assignment(self) -> int | None:
        return None if self.held in self._dummies else self.held

    @property
    def converged(self) -> bool:
        return (bool(self.schedule) and self.phase == len(self.schedule) - 1 and self.held is not None
                and self._full() and self._now - self._last_change >= self.quiet)

    @property
    def eps(self) -> float:
        return self.schedule[self.phase] if self.schedule else INF

    @property
    def rung(self) -> int:
        """Rungs left above the final eps (0: on it); ``NO_RUNG`` before the task set is known."""
        return len(self.schedule) - 1 - self.phase if self.schedule else NO_RUNG

    def _fleet_caught_up(self) -> bool:
        """Every live peer has reported a rung no higher than mine."""
        mine = self.rung
        return all(self._peer_rung.get(p, NO_RUNG) <= mine for p in self.alive)

    def start(self, tasks: Mapping[int, tuple[float, float]], now: float) -> list:
        self._now = now
        self._initiator = self._active = True
        self._active_since = now
        self._last_change = now
        self.book.set_all(tasks)
        out = self._task_set(BROADCAST)
        out += self._ready(now)
        return self._out(out)

    def on_message(self, msg, now: float) -> list:
        self._now = now
        if not addressed_to(msg, self.robot_id):
            self.dropped["not for me"] += 1
            return []
        sender = msg.sender
        handler = {Price: self._on_price, TaskInfo: self._on_taskinfo, Status: self._on_status}.get(type(msg))
        if handler is None:
            self.dropped["unexpected type"] += 1
            return []
        self.heard(sender, now)
        if sender in self.peers and sender not in self.alive:
            self.alive.add(sender)
            self._sync_dummies(now)
        if not self._active:
            self._active, self._active_since, self._last_change = True, now, now
        return self._out(handler(msg, now))

    def on_tick(self, now: float) -> list:
        self._now = now
        out = []
        if self.schedule and self.held is None:
            out += self._bid(now)
        full = self._full()
        still = now - self._last_change
        quiet = (full and still >= self.settle) or still >= 2 * self.settle
        stepping = bool(self.schedule) and self.phase < len(self.schedule) - 1 and quiet
        if stepping and self._fleet_caught_up():
            self.phase += 1
            self._last_change = now
            rebid = self._recheck(now)
            out += rebid
            if not rebid and self.held is not None:
                out.append(self._entry(self.held, BROADCAST))      # my new rung, for the others' barrier
        elif ((not full or stepping or not self.schedule) and self._active
              and now - self._last_solicit >= self.bid_timeout
              and (still >= self.bid_timeout
                   or (not self.schedule and now - self._active_since >= self.bid_timeout))):
            # missing entries, a peer's rung (I wait at the barrier) or part of the task set: ask
            self._last_solicit = now
            out.append(Status(self.robot_id, BROADCAST, 0, NO_TASK if self.held is None else self.held, False))
        if self.held is not None and now - self._last_own >= self.keepalive:
            out.append(self._entry(self.held, BROADCAST))
        out += self._resend_notices(now)
        out += self._check_suspects(now)
        return self._out(out)

    def _resend_notices(self, now: float) -> list:
        """A robot I outbid has not bid again: it may have missed my Price, tell it directly."""
        out = []
        for robot, notice in list(self._notices.items()):
            task, deadline, tries = notice
            if now < deadline:
                continue
            if self.held != task or tries >= 3 or robot not in self.alive:
                del self._notices[robot]
                continue
            notice[1], notice[2] = now + self.settle, tries + 1
            out.append(self._entry(task, robot))
        return out

    def on_peer_lost(self, robot_id: int, now: float) -> list:
        """A peer declared lost (no heartbeat for a while) that holds a task in my table is asked directly first: a
        lossy link makes live robots look lost now and then, and freeing their tasks at once had robots with
        nothing bid for them and the holders, alive, bid their way back, for good in a round of ten robots in
        loss spells.  It stays among the live robots for ``LOST_PROBES`` bid timeouts, asked once each (a
        ``Status`` to it, which a holder answers with its entry); heard in that time (any of its messages, or
        :meth:`heard`), it was not lost after all.  A peer holding nothing in my table is lost at once.  A suspect
        does not keep me from having converged: my own assignment stands."""
        self._now = now
        if robot_id not in self.alive or robot_id in self._suspects:
            return []
        if any(h == robot_id for h in self.holder.values()):
            self._suspects[robot_id] = [now, 1]
            return self._out([self._probe(robot_id)])
        return self._out(self._lose(robot_id, now))

    def heard(self, robot_id: int, now: float) -> None:
        """Robot ``robot_id`` was heard (any message reaching my daemon, its state most often): not lost after all."""
        self._suspects.pop(robot_id, None)

    def _probe(self, robot_id: int) -> Status:
        return Status(self.robot_id, robot_id, 0, NO_TASK if self.held is None else self.held, False)

    def _check_suspects(self, now: float) -> list:
        out = []
        for robot, probe in list(self._suspects.items()):
            if now - probe[0] < self.bid_timeout:
                continue
            if probe[1] >= LOST_PROBES:
                del self._suspects[robot]
                out += self._lose(robot, now)
            else:
                probe[0], probe[1] = now, probe[1] + 1
                out.append(self._probe(robot))
        return out

    def _lose(self, robot_id: int, now: float) -> list:
        """The lost robot's task becomes free at its price; whoever now prefers it bids for it."""
        self.alive.discard(robot_id)
        for task, h in list(self.holder.items()):
            if h == robot_id:
                self._set(task, self.price[task], 0)
                self._last_change = now
                self.log.info("robot %d lost: task %d is free again", robot_id, task)
        self._sync_dummies(now)
        return self._bid(now) if self.held is None and self.schedule else []

    # ------------------------------------------------------------------ bidding
    def _ready(self, now: float) -> list:
        """Once the whole task set is known: the eps schedule, then a first bid."""
        if self.schedule or not self.book.complete:
            return []
        costs = [self.book.cost(t) for t in self.book.positions]
        cmax = max((c for c in costs if math.isfinite(c)), default=0.0)
        n = len(costs)
        final = self.eps_final if self.eps_final is not None else self.cost_unit / (n + 1)
        top = 0
        while final * self.theta ** top < cmax / self.theta and top < NO_RUNG - 1:
            top += 1
        self.schedule = [final * self.theta ** k for k in range(top, -1, -1)]
        for t in self.book.positions:
            self.price.setdefault(t, 0.0)
            self.holder.setdefault(t, 0)
        self._sync_dummies(now)
        self._last_change = now
        return self._bid(now) if self.held is None else []

    def _sync_dummies(self, now: float) -> None:
        """One zero-cost "no task" slot per robot beyond N_T (ids from the top of the id range), so
        that surplus robots settle instead of bidding prices up for ever."""
        if not self.schedule:
            return
        want = {MAX_TASKS - 1 - k for k in range(max(0, len(self.alive) + 1 - self.book.n_tasks))}
        for d in self._dummies - want:
            self._set(d, self.price[d], 0)
            del self.price[d], self.holder[d]
            if self.held == d:
                self.held = None
        for d in want - self._dummies:
            self.price.setdefault(d, 0.0)        # a Price for it may have come first
            self.holder.setdefault(d, 0)
        if want != self._dummies:
            self._dummies = want
            self._last_change = now

    def _cost(self, task: int) -> float:
        return 0.0 if task in self._dummies else self.book.cost(task)

    def _values(self, out_of_reach=()):
        for t in list(self.book.positions) + sorted(self._dummies):
            c = self._cost(t)
            if math.isfinite(c) and t not in out_of_reach:
                yield -c - self.price.get(t, 0.0), t

    def _best(self, out_of_reach) -> tuple[float, int | None, float]:
        best_v, best_t, second_v = -INF, None, -INF
        for v, t in self._values(out_of_reach):
            if best_t is None or v > best_v or (v == best_v and t < best_t):
                if best_t is not None:
                    second_v = max(second_v, best_v)
                best_v, best_t = v, t
            else:
                second_v = max(second_v, v)
        return best_v, best_t, second_v

    def _bid(self, now: float) -> list:
        """Bid for my best task.  A task whose price I would have to raise past the protocol's largest price
        (``MAX_VALUE``: a price my peers refuse) is out of reach and I bid for the next best: in an unsigned fleet a
        forged Price at the maximum must not make every genuine bid for that task one its peers refuse."""
        out_of_reach: set[int] = set()
        while True:
            best_v, best_t, second_v = self._best(out_of_reach)
            if best_t is None:
                return []
            increment = (best_v - second_v if second_v > -INF else 0.0) + self.eps
            if self.price.get(best_t, 0.0) + increment <= MAX_VALUE:
                break
            out_of_reach.add(best_t)
        task = best_t
        new = self.price.get(task, 0.0) + increment
        displaced = self.holder.get(task, 0)
        if displaced and displaced != self.robot_id and displaced in self.alive:
            self._notices[displaced] = [task, now + self.settle, 0]
        self._set(task, new, self.robot_id)
        self.held = task
        self.bids += 1
        self._last_change = now
        return [self._entry(task, BROADCAST)]

    def _recheck(self, now: float) -> list:
        """Keep my task under the new eps only if it is within eps of my best value."""
        if self.held is None:
            return self._bid(now)
        mine = -self._cost(self.held) - self.price[self.held]
        best = max((v for v, _ in self._values()), default=mine)
        if mine >= best - self.eps:
            return []
        self.held = None
        return self._bid(now)

    def _entry(self, task: int, dest: int) -> Price:
        if self.holder.get(task) == self.robot_id:
            self._last_own = self._now
        return Price(self.robot_id, dest, task, self.holder.get(task, 0), self.price.get(task, 0.0), self.rung)

    # ------------------------------------------------------------------ table
    def _set(self, task: int, price: float, holder: int) -> None:
        old = self.holder.get(task, 0)
        if old:
            self._holders[old] -= 1
            if not self._holders[old]:
                del self._holders[old]
        if holder:
            self._holders[holder] += 1
        self.price[task] = price
        self.holder[task] = holder

    def _full(self) -> bool:
        """My table shows every live robot (up to N_T of them) holding a task.  A robot may appear on two
        tasks: one it left when a new eps made another better, or one whose displacement I have not heard
        of yet.  With fewer robots than tasks nobody takes the task it left, so counting entries instead of
        robots would keep the fleet from converging; the left task is simply open at its price."""
        if self.book.n_tasks is None:
            return False
        target = min(self.book.n_tasks + len(self._dummies), len(self.alive) + 1)
        return len(self._holders) == target

    # ------------------------------------------------------------------ messages
    def _on_price(self, m: Price, now: float) -> list:
        if self.book.complete and m.task not in self.book.positions and m.task not in self._dummies:
            self.dropped["unknown task"] += 1
            return []
        if m.holder != m.sender and not (m.holder == m.dest == self.robot_id and self.held == m.task):
            self.dropped["price held by a robot other than its sender"] += 1
            return []
        if m.phase != NO_RUNG and m.sender in self.peers:
            self._peer_rung[m.sender] = min(m.phase, self._peer_rung.get(m.sender, NO_RUNG))
        notice = self._notices.get(m.sender)
        if notice is not None and m.holder == m.sender and m.task != notice[0]:
            del self._notices[m.sender]                  # it has bid elsewhere: it knows
        cur_p, cur_h = self.price.get(m.task, 0.0), self.holder.get(m.task, 0)
        new_key, cur_key = (m.price, -m.holder), (cur_p, -cur_h)
        if new_key > cur_key:
            self._set(m.task, float(m.price), m.holder)
            self._last_change = now
            if self.held == m.task and m.holder != self.robot_id:
                self.held = None
                return self._bid(now) if self.schedule else []
            return []
        if new_key < cur_key and cur_h == self.robot_id:
            return [self._entry(m.task, m.sender)]       # the sender's view is stale
        if new_key < cur_key and cur_h == 0 and m.holder == m.sender and m.sender in self.alive:
            # The task was freed when its holder was lost, and the sender still claims it at an older, lower
            # price: it never heard the lost robot outbid it.  Nobody else holds it, so the claim stands, at the
            # price I know; telling the sender that price makes our tables agree.
            self._set(m.task, cur_p, m.sender)
            self._last_change = now
            return [self._entry(m.task, m.sender)]
        return []

    def _on_taskinfo(self, m: TaskInfo, now: float) -> list:
        if not self.book.learn(m.task, m.x, m.y, m.n_tasks):
            self.dropped["contradicts task set"] += 1
            return []
        if self._task_source is None:
            self._task_source = m.sender
        return self._ready(now)

    def _on_status(self, m: Status, now: float) -> list:
        if m.converged:
            return []
        out = []
        if self.held is not None and self._serve("entry", now):
            out.append(self._entry(self.held, BROADCAST))
        source_lost = self._task_source is not None and self._task_source not in self.alive
        if (m.task == NO_TASK and (self._initiator or (source_lost and self.book.complete))
                and self._serve("tasks", now)):
            out += self._task_set(BROADCAST)
        return out

    def _serve(self, what: str, now: float) -> bool:
        """Answers to Status go to everyone, at most once per bid_timeout of each kind."""
        if now - self._served.get(what, -INF) < self.bid_timeout:
            return False
        self._served[what] = now
        return True

    def _task_set(self, dest: int) -> list:
        n = len(self.book.positions)
        return [TaskInfo(self.robot_id, dest, t, x, y, n) for t, (x, y) in sorted(self.book.positions.items())]

    def _out(self, msgs: list) -> list:
        self.sent += len(msgs)
        return msgs
