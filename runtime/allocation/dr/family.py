"""Paper 000's Double Round auction (Guerrero & Oliver) as a daemon allocation method (``dr``) for ``transport``
tasks; its variants SR and Greedy and the strategies M/NM x I/NI are options (docs/dr.md).

:class:`DrAgent` is one robot's sans-IO agent.  At any time a robot is free, a candidate for a task's leadership
(Alg. 1), its leader (Alg. 2, :mod:`~runtime.allocation.dr.leader`), a member of a leader's group (Alg. 3,
:mod:`~runtime.allocation.dr.member`), or a carrier (it left a group with a load on board and delivers it); never
two of these.  It holds at most one commitment: the task it works on, role ``leader``, ``member`` or ``carrier``,
with the executor's parameters (delivery point, load per trip, load time per wu, reach).

Execution reports ``loaded``/``delivered``; the robot's reports (:class:`~runtime.allocation.dr.ledger.Outbox`)
go to the task's leader, which grants loads from the weight left and keeps the books
(:mod:`~runtime.allocation.dr.ledger`).  Learning: :mod:`~runtime.allocation.dr.learning`.

Messages the agent addresses to itself (the leader's own reports and grants) are handled without touching the
wire; broadcasts go to the wire and to itself.  Every message from outside is checked once more (``invalid()``:
in-memory tests hand over objects the codec never made); what cannot be acted on is counted in
:attr:`DrAgent.dropped` by reason.
"""
from __future__ import annotations

import math
from collections import Counter
from pathlib import Path
from typing import Sequence

from runtime.allocation.agent import FAILED, AgentContext, Method, TaskEvent, route
from runtime.allocation.dr import model as M
from runtime.allocation.dr.interference import InterferenceModel
from runtime.allocation.dr.leader import Finish, Leader, LeaderView
from runtime.allocation.dr.learning import Learning
from runtime.allocation.dr.ledger import EPS, Entry, Outbox
from runtime.allocation.dr.member import Membership, Offer, Offers, Request, better
from runtime.allocation.dr.messages import (FINISHED, NOT_MEMBER, REASONS, WIRE_MESSAGES, YIELD, DrAward, DrBid,
                                            DrBidRequest, DrDeliver, DrExitLeader, DrLeaderAlive, DrLeaderRequest, DrLedger,
                                            DrLoad, DrRefuse, DrRobotAlive, DrSampleRequest, DrSvrSample)
from runtime.allocation.dr.options import DrOptions
from runtime.allocation.dr.world import TaskInfo, World
from runtime.errors import InputError
from runtime.messages import BROADCAST, RobotState, task_origin, why_invalid
from runtime.log import get_logger
from runtime.tasks import FAILED as P_FAILED, Commitment, Progress, Task
from runtime.tasks.transport import DELIVERED, LOADED

KINDS = ("transport",)
LEADER, MEMBER, CARRIER, CANDIDATE = "leader", "member", "carrier", "candidate"
_models: dict[tuple, InterferenceModel] = {}        # (path, mtime, size) -> the file's model, copied per robot


def load_model(path: Path) -> InterferenceModel:
    """The model in ``path`` (parsed and fitted once per file version in a process), as a copy of its own."""
    try:
        st = path.stat()
        key = (str(path.resolve()), st.st_mtime_ns, st.st_size)
    except OSError:
        key = None
    model = _models.get(key) if key else None
    if model is None:
        model = InterferenceModel.load(path)
        if key:
            _models[key] = model
    return model.copy()


class DrAgent:
    """One robot's dr-family agent (see the module docstring)."""

    def __init__(self, ctx: AgentContext):
        self.robot_id = int(ctx.robot_id)
        self.o: DrOptions = ctx.options
        self.estimator = ctx.estimator
        self.log = get_logger("alloc.dr", self.robot_id)
        self.world = World(self.robot_id, ctx.peers, self.o)
        self.events: list[TaskEvent] = []
        self.dropped: Counter = Counter()
        self.available = True
        self.localized = True
        self.request: Request | None = None
        self.lead: Leader | None = None
        self.membership: Membership | None = None
        self.carrying: int | None = None              # task of the load a carrier delivers
        self._committed: tuple | None = None          # (task, partners, role, commitments) last returned
        self.carrier_requests = 0                      # times it asked to lead as a carrier (``carrier_leads``)
        self.offers = Offers()
        self.outboxes: dict[int, Outbox] = {}
        self.accounts: dict[int, Entry] = {}           # task -> this robot's own entry (kept after the task ends)
        self.finished: dict[int, Finish] = {}          # tasks this robot completed as their leader
        self.gave_up: dict[int, float] = {}            # task -> when this robot gave up asking to lead it
        path = self.o.model_path()
        try:
            self.model = load_model(path) if path is not None else InterferenceModel(source="none: learnt on-line")
        except InputError as exc:
            raise InputError(f"{self.o.source or '<config>'}: allocation.model: {exc}") from None
        if path is None and self.o.interference:
            self.log.warning("strategy %s without an interference model file: I = 0 until samples are learnt",
                             self.o.strategy)
        self.learning = Learning(self.robot_id, self.model, self.o, self.log)
        self.now = 0.0
        self._refused: set[int] = set()

    # ------------------------------------------------------------------ the robot's model of itself
    @property
    def speed(self) -> float:
        """m/s this robot believes it drives at (eq. 5)."""
        return float(self.o.speed_belief if self.o.speed_belief is not None else self.estimator.profile.speed)

    def capacity(self, info: TaskInfo) -> float:
        return M.work_capacity(self.o.load_capacity, self.speed, info.distance, self.o.load_time)

    def interference(self, n: float, d: float) -> float:
        return self.model.predict(n, d)

    def set_model(self, model: InterferenceModel) -> None:
        """Use ``model`` (e.g. one fitted in-process by an experiment); this robot learns on its own copy."""
        self.model = model.copy()
        self.learning.model = self.model

    # ------------------------------------------------------------------ what the daemon and tests read
    def role(self, task: int) -> str | None:
        if self.lead is not None and self.lead.task == task:
            return LEADER
        if self.membership is not None and self.membership.task == task:
            return MEMBER
        if self.carrying == task:
            return CARRIER
        if self.request is not None and self.request.task == task:
            return CANDIDATE
        return None

    @property
    def job(self) -> int | None:
        """The task this robot is engaged in (leading, member, carrying, or asking to lead), if any."""
        for t in (self.lead and self.lead.task, self.membership and self.membership.task, self.carrying,
                  self.request and self.request.task):
            if t:
                return t
        return None

    def coalitions(self) -> tuple[int, ...]:
        """Tasks whose group this robot is in, as it sees it (the leader is in its own): never more than one."""
        return tuple(t for t in (self.lead and self.lead.task, self.membership and self.membership.task) if t)

    def leader_view(self, task: int) -> LeaderView | None:
        return self.lead.view(self.now) if self.lead is not None and self.lead.task == task else None

    @property
    def commitments(self) -> tuple[Commitment, ...]:
        t, role, partners = None, "", ()
        if self.lead is not None and (self.lead.working or self._loaded(self.lead.task)):
            t, role, partners = self.lead.task, LEADER, tuple(r for r in self.lead.group() if r != self.robot_id)
        elif self.membership is not None:
            t, role, partners = self.membership.task, MEMBER, self.membership.partners
        elif self.carrying is not None:
            t, role = self.carrying, CARRIER
        info = self.world.tasks.get(t) if t is not None else None
        if info is None or info.task is None:
            return ()
        last = self._committed                  # read several times a cycle: the same answer, built once
        if last is not None and last[0] is info.task and last[1] == partners and last[2] == role:
            return last[3]
        params = (("delivery", tuple(self.o.delivery)), ("load", self.o.load_capacity),
                  ("load_time", self.o.load_time), ("reach", self.o.reach),
                  ("delivery_reach", self.o.delivery_reach or self.o.reach))
        out = (Commitment(info.task, partners, role, params),)
        self._committed = (info.task, partners, role, out)
        return out

    @property
    def converged(self) -> bool:
        lead = self.lead
        return (self.request is None and not self.offers
                and (lead is None or (lead.round is None and not lead.pending)))

    @property
    def allocating(self) -> bool:
        return self.request is not None or bool(self.offers)

    def pop_events(self) -> list[TaskEvent]:
        out, self.events = self.events, []
        return out

    def _free(self) -> bool:
        return (self.available and self.localized and self.lead is None and self.membership is None
                and self.carrying is None and self.request is None)

    def _loaded(self, task: int) -> bool:
        box = self.outboxes.get(task)
        return box is not None and box.loaded

    def _outbox(self, task: int) -> Outbox:
        box = self.outboxes.get(task)
        if box is None:
            box = self.outboxes[task] = Outbox(self.robot_id, task, self.accounts.setdefault(task, Entry()))
        return box

    # ------------------------------------------------------------------ inputs
    def add_tasks(self, tasks: Sequence[Task], now: float) -> list:
        self.now = now
        for t in tasks:
            if t.kind in KINDS:
                if t.id not in self.world.closed:
                    self.world.add(t, now)
            elif t.id not in self._refused:
                self._refused.add(t.id)
                self.log.warning("task %d is a %s: the dr method allocates transport tasks only", t.id, t.kind)
                if task_origin(t.id) == self.robot_id:        # reported once, by the robot that took it in
                    self.events.append(TaskEvent(t.id, FAILED, (self.robot_id,),
                                                 f"{t.kind} tasks are not allocated by the dr method"))
        return []

    def withdraw_tasks(self, task_ids: Sequence[int], now: float) -> list:
        self.now = now
        for t in task_ids:
            self.world.close(t)
            self.outboxes.pop(t, None)
            self.gave_up.pop(t, None)
            self.offers.by_leader = {k: o for k, o in self.offers.by_leader.items() if o.task != t}
            if self.lead is not None and self.lead.task == t:
                if self.lead.finished is not None:
                    self.finished[t] = self.lead.finished
                self.lead = None
            if self.membership is not None and self.membership.task == t:
                self.membership = None
            if self.carrying == t:
                self.carrying = None
            if self.request is not None and self.request.task == t:
                self.request = None
        return []

    def set_available(self, available: bool, now: float) -> list:
        self.now = now
        self.available = bool(available)
        if available:
            return []
        return self._route(self._abandon("disarmed", now), now)

    def set_localized(self, localized: bool) -> None:
        self.localized = bool(localized)

    def on_peer_joined(self, robot_id: int, now: float) -> list:
        """A robot joined the fleet: its messages count from now (its leadership requests, bids and reports).  A
        leader's auction under way keeps the bids it has; the joiner bids in the next one it hears of."""
        self.now = now
        self.world.join(robot_id)
        return []

    def on_peer_lost(self, robot_id: int, now: float) -> list:
        self.now = now
        if not self.world.known(robot_id):
            return []
        self.world.lost.add(robot_id)
        out = []
        m = self.membership
        if m is not None and m.leader == robot_id:
            out += self._leave(f"leader {robot_id} lost", now)
        if self.lead is not None and robot_id in self.lead.members:
            self.lead.drop(robot_id, now, "lost")
        return self._route(out, now)

    def on_progress(self, p: Progress, now: float) -> list:
        self.now = now
        task = p.task
        engaged = task in (self.lead and self.lead.task, self.membership and self.membership.task, self.carrying)
        if not engaged:
            return []
        box = self._outbox(task)
        out = []
        if p.event == LOADED:
            box.loaded_now(float(p.data.get("wu", self.o.load_capacity)))
        elif p.event == DELIVERED:
            box.unloaded_now()
        elif p.event == P_FAILED:
            out += self._abandon(f"execution failed: {p.detail}", now)
        out += self._reports(now)
        out += self._after_unload(now)
        return self._route(out, now)

    def on_message(self, msg, now: float) -> list:
        self.now = now
        sender = getattr(msg, "sender", None)
        if isinstance(msg, RobotState):
            if self.world.known(sender) and self.world.on_state(msg):
                self.world.heard(sender, now)
                if self.lead is not None and self.lead.task in msg.tasks:
                    self.lead.heard_from(sender, now)
            else:
                self.dropped["bad state"] += 1
            return []
        why = (not isinstance(msg, WIRE_MESSAGES) and "not a dr message"
               or not self.world.known(sender) and "not a robot of the fleet"
               or getattr(msg, "dest", None) not in (BROADCAST, self.robot_id) and "not for me"
               or why_invalid(msg) and "invalid")
        if why:
            self.dropped[why] += 1
            return []
        self.world.heard(sender, now)
        return self._route(self._dispatch(msg, now), now)

    def on_tick(self, now: float) -> list:
        self.now = now
        out = []
        if self.lead is not None:
            out += self.lead.tick(now)
            if self.lead.finished is not None:
                out += self._end_lead(now)
        out += self._member_tick(now)
        out += self._offers_tick(now)
        out += self._request_tick(now)
        out += self._reports(now)
        out += self._after_unload(now)
        out += self.learning.tick(now)
        return self._route(out, now)

    def quiet(self, now: float) -> bool:
        """True when :meth:`on_tick` at ``now`` would send nothing and change nothing (its ``now`` aside, which
        only a leader's view reads): every branch of the tick is tested with the tick's own comparisons, and any
        branch this cannot settle cheaply (a leader's, a free robot's search for a task) counts as busy.  The
        fleet node skips quiet ticks (:meth:`runtime.fleet.node.FleetNode.tick`)."""
        if self.lead is not None or self.events:
            return False
        o, ms = self.o, self.membership
        if ms is not None and (now - ms.leader_heard > o.leader_timeout or now >= ms.next_alive):
            return False                                           # _member_tick
        if self.offers and now >= self.offers.until:
            return False                                           # _offers_tick
        r = self.request                                           # _request_tick
        if r is not None:
            if now - r.since > o.time_leadership:
                return False
        elif not self.offers and (self._free() or o.carrier_leads and self._carrier_only()):
            return False
        for task, box in self.outboxes.items():                    # _reports
            info = self.world.tasks.get(task)
            if info is None or box.head is None and box.queue:
                return False
            if box.head is not None and now - box.sent >= o.report_resend:
                to = self.world.leader_of(info, now)
                if self.lead is not None and self.lead.task == task:
                    to = self.robot_id
                elif ms is not None and ms.task == task:
                    to = ms.leader
                if to is not None:
                    return False
            if box.idle and task not in (ms and ms.task, self.carrying):
                return False
        if self.carrying is not None and not self._loaded(self.carrying):
            return False                                           # _after_unload
        if ms is not None and not self._loaded(ms.task):
            info = self.world.tasks.get(ms.task)
            if info is not None and info.left_heard is not None and info.left_heard <= EPS:
                return False
        lr = self.learning                                         # learning.tick
        return not lr.own or now - lr.repeated < o.sample_period

    # ------------------------------------------------------------------ dispatch
    def _dispatch(self, m, now: float) -> list:
        task = getattr(m, "task", None)
        if task is not None and task in self.world.closed:
            self.dropped["task closed"] += 1
            return []
        handler = _HANDLERS.get(type(m))
        return handler(self, m, now) or []

    def _leading(self, m) -> bool:
        if self.lead is not None and self.lead.task == m.task:
            return True
        self.dropped["not its leader"] += 1
        return False

    def _on_leader_request(self, m: DrLeaderRequest, now: float) -> list:
        info = self.world.info(m.task)
        if info is None or m.sender == self.robot_id:
            return []
        info.claims[m.sender] = (m.capacity, now)
        r = self.request
        if r is not None and r.task == m.task and better(m.capacity, m.sender, r.capacity, self.robot_id):
            self.log.info("task %d: robot %d is a better candidate: giving up", m.task, m.sender)
            self.request, self.gave_up[m.task] = None, now
        if self.lead is not None and self.lead.task == m.task:
            self.lead.next_alive = now                  # tell the candidate at once
        return []

    def _on_bid_request(self, m: DrBidRequest, now: float) -> list:
        if m.sender != self.robot_id:                        # only a leader of the task auctions it
            leading = self.lead is not None and self.lead.task == m.task
            out = self._other_leads(m.task, m.sender, now)
            if leading:
                return out
        info = self.world.tasks.get(m.task)
        if not self._free() or info is None or info.task is None or m.sender in self.world.lost:
            return []
        est = self.estimator.estimates([info.task])[0]
        distance = est.cost if math.isfinite(est.cost) else 1e6
        return [DrBid(self.robot_id, m.sender, m.task, m.round, self.capacity(info), distance)]

    def _on_bid(self, m: DrBid, now: float) -> list:
        if self._leading(m) and not self.lead.on_bid(m, now):
            self.dropped["bid out of round"] += 1
        return []

    def _on_award(self, m: DrAward, now: float) -> list:
        ms = self.membership
        if ms is not None and ms.task == m.task and ms.leader == m.sender:
            return [self._alive_msg(ms)]                   # a resent award: confirm again
        info = self.world.tasks.get(m.task)
        if not self._free() or info is None or info.task is None:
            return [DrRefuse(self.robot_id, m.sender, m.task, m.round)]
        if self.o.auction != "dr":                         # SR, Greedy: the first agreement received
            return self._join(m.sender, m.task, now)
        est = self.estimator.estimates([info.task])[0]
        self.offers.add(Offer(m.sender, m.task, m.round, m.value, est.cost), now, self.o.time_bid_accepted)
        return []

    def _on_robot_alive(self, m: DrRobotAlive, now: float) -> list:
        if self.lead is not None and self.lead.task == m.task:
            return self.lead.on_robot_alive(m, now)
        self.dropped["not its leader"] += 1
        return [DrExitLeader(self.robot_id, m.sender, m.task, NOT_MEMBER)]

    def _on_refuse(self, m: DrRefuse, now: float) -> list:
        if self._leading(m):
            self.lead.on_refuse(m, now)
        return []

    def _on_leader_alive(self, m: DrLeaderAlive, now: float) -> list:
        info = self.world.info(m.task)
        if info is None:
            self.dropped["too many unknown tasks"] += 1
            return []
        info.appeared = min(info.appeared, now - m.appeared_age)
        if m.sender == self.robot_id:
            return []
        info.leader, info.leader_heard, info.alive, info.alive_at, info.left_heard = m.sender, now, m, now, m.left
        out = self._other_leads(m.task, m.sender, now)
        ms = self.membership
        if ms is not None and ms.task == m.task and ms.leader == m.sender:
            ms.leader_heard = now
            ms.partners = tuple(r for r in m.members if r != self.robot_id)
        return out

    def _other_leads(self, task: int, other: int, now: float) -> list:
        """Robot ``other`` leads ``task`` (its LEADER_ALIVE or its BID_REQUEST said so).  A candidate for it gives
        up.  If this robot leads it too, the higher id keeps it: yield to a higher id; to a lower one, send
        LEADER_ALIVE at once so it yields."""
        if self.request is not None and self.request.task == task:
            self.log.info("task %d: robot %d leads it already: giving up", task, other)
            self.request, self.gave_up[task] = None, now
        if self.lead is None or self.lead.task != task:
            return []
        if other in self.lead.members:                 # a robot that leads the task is no member of mine (its
            self.lead.drop(other, now, "it leads the task itself")     # state naming the task is no keep-alive)
        if other > self.robot_id:
            return self.lead.resign(YIELD, now, f"robot {other} leads it too and has the higher id") + self._end_lead(now)
        self.lead.next_alive = now
        return []

    def _on_exit(self, m: DrExitLeader, now: float) -> list:
        if (m.reason == FINISHED and m.sender != self.robot_id and self.lead is not None
                and self.lead.task == m.task):             # another leader of the task finished it: one DONE
            return self.lead.resign(YIELD, now, f"robot {m.sender} finished it") + self._end_lead(now)
        info = self.world.tasks.get(m.task)
        if m.dest == BROADCAST and info is not None and info.leader == m.sender:
            info.leader = None                              # it no longer leads: the task is free to lead
        ms = self.membership
        if ms is not None and ms.task == m.task and ms.leader == m.sender:
            return self._leave(f"robot {m.sender} says: {REASONS[m.reason]}", now)
        return []

    def _on_sample(self, m: DrSvrSample, now: float) -> list:
        return self.learning.on_sample(m, now)

    def _on_sample_request(self, m: DrSampleRequest, now: float) -> list:
        return self.learning.on_request(m)

    def _on_load(self, m: DrLoad, now: float) -> list:
        return self.lead.on_load(m, now) if self._leading(m) else []

    def _on_deliver(self, m: DrDeliver, now: float) -> list:
        return self.lead.on_deliver(m, now) if self._leading(m) else []

    def _on_ledger(self, m: DrLedger, now: float) -> list:
        info = self.world.info(m.task)
        if info is None:
            self.dropped["too many unknown tasks"] += 1
            return []
        if not info.ledger.plausible(m.robot, m.taken, m.delivered, m.returned):
            self.dropped["entry beyond the object's weight"] += 1
            return []
        info.ledger.merge(m.robot, m.loads, m.taken, m.deliveries, m.delivered, m.returned)
        self.world.mentioned(m.robot, now)
        if m.sender == info.leader or m.sender == self.robot_id:
            info.left_heard = m.left
        ms = self.membership
        if ms is not None and ms.task == m.task and ms.leader == m.sender:
            ms.leader_heard = now
            info.left_heard = m.left
        if m.robot == self.robot_id and m.task in self.outboxes:
            self.outboxes[m.task].on_ledger(m)
            return self._after_unload(now)
        return []

    # ------------------------------------------------------------------ roles
    def _request_tick(self, now: float) -> list:
        r = self.request
        if r is not None:
            if now - r.since <= self.o.time_leadership:
                return []
            self.request = None
            info = self.world.tasks.get(r.task)
            if info is None or info.task is None or not self.available or not self.localized:
                return []
            if self.carrying == r.task:
                self.carrying = None                        # the load on board is the leader's own now
            self.lead = Leader(self, info, now)
            return self.lead.start(now)
        if self.offers:
            return []
        if self._free():
            info = self._nearest_leaderless(now)
        elif self.o.carrier_leads and self._carrier_only():
            info = self._nearest_leaderless(now, only=self.carrying)
            self.carrier_requests += info is not None
        else:
            return []
        if info is None:
            return []
        self.request = Request(info.id, now, self.capacity(info))
        self.log.info("asking to lead task %d", info.id)
        return [DrLeaderRequest(self.robot_id, BROADCAST, info.id, self.request.capacity)]

    def _carrier_only(self) -> bool:
        """Carrying a load and nothing else (``carrier_leads``: it may ask to lead the task of that load)."""
        return (self.carrying is not None and self.available and self.localized and self.lead is None
                and self.membership is None and self.request is None)

    def _nearest_leaderless(self, now: float, only: int | None = None) -> TaskInfo | None:
        window = self.o.time_leadership + self.o.leader_alive_period + self.o.time_auction
        cands = [i for i in self.world.open_tasks()
                 if not i.ledger.done and self.world.leader_of(i, now) is None and not self.world.claimed(i, now)
                 and now - self.gave_up.get(i.id, -math.inf) > window and only in (None, i.id)]
        if not cands:
            return None
        costs = [e.cost for e in self.estimator.estimates([i.task for i in cands])]
        best = min(range(len(cands)), key=lambda k: (costs[k], cands[k].id))
        return cands[best] if math.isfinite(costs[best]) else None

    def _offers_tick(self, now: float) -> list:
        if not self.offers or now < self.offers.until:
            return []
        ranked = self.offers.ranked()
        self.offers.clear()
        out, chosen = [], None
        for o in ranked:
            info = self.world.tasks.get(o.task)
            if chosen is None and self._free() and info is not None and o.leader not in self.world.lost:
                chosen = o
                out += self._join(o.leader, o.task, now)
            else:
                out.append(DrRefuse(self.robot_id, o.leader, o.task, o.round))
        return out

    def _join(self, leader: int, task: int, now: float) -> list:
        self.offers.clear()
        self.membership = Membership(task, leader, now, now, now + self.o.member_alive_period, (leader,))
        self.log.info("member of task %d led by robot %d", task, leader)
        return [self._alive_msg(self.membership)]

    def _alive_msg(self, ms: Membership) -> DrRobotAlive:
        e = self._outbox(ms.task).mine
        return DrRobotAlive(self.robot_id, ms.leader, ms.task, e.loads, e.taken, e.deliveries, e.delivered,
                            e.returned)

    def _member_tick(self, now: float) -> list:
        ms = self.membership
        if ms is None:
            return []
        if now - ms.leader_heard > self.o.leader_timeout:
            return self._leave(f"leader {ms.leader} silent for {self.o.leader_timeout:g} s", now)
        if now < ms.next_alive:
            return []
        ms.next_alive = now + self.o.member_alive_period
        return [self._alive_msg(ms)]

    def _after_unload(self, now: float) -> list:
        """A carrier that has delivered is free; a member with nothing left to fetch and nothing on board leaves."""
        if self.carrying is not None and not self._loaded(self.carrying):
            self.carrying = None
        ms = self.membership
        if ms is not None and not self._loaded(ms.task):
            info = self.world.tasks.get(ms.task)
            if info is not None and info.left_heard is not None and info.left_heard <= EPS:
                return self._leave("nothing left at the object", now)
        return []

    def _leave(self, why: str, now: float, tell: bool = False) -> list:
        ms, self.membership = self.membership, None
        if ms is None:
            return []
        self.log.info("leaving the group of task %d: %s", ms.task, why)
        if self._loaded(ms.task):
            self.carrying = ms.task
        return [DrRefuse(self.robot_id, ms.leader, ms.task, 0)] if tell else []

    def _end_lead(self, now: float) -> list:
        lead, self.lead = self.lead, None
        if lead.finished is not None:
            self.finished[lead.task] = lead.finished
        elif self._loaded(lead.task):
            self.carrying = lead.task
        return []

    def _abandon(self, why: str, now: float) -> list:
        """Disarmed or execution failed: the load on board goes back to the object and the robot leaves it all."""
        out = []
        for box in self.outboxes.values():
            box.put_back()
        if self.lead is not None:
            out += self.lead.resign(YIELD, now, why)
            out += self._end_lead(now)
        out += self._leave(why, now, tell=True)
        self.carrying = None
        self.request = None
        for o in self.offers.ranked():
            out.append(DrRefuse(self.robot_id, o.leader, o.task, o.round))
        self.offers.clear()
        return out + self._reports(now)

    def _reports(self, now: float) -> list:
        out = []
        for task, box in list(self.outboxes.items()):
            info = self.world.tasks.get(task)
            if info is None:
                del self.outboxes[task]
                continue
            to = self.world.leader_of(info, now)
            if self.lead is not None and self.lead.task == task:
                to = self.robot_id
            elif self.membership is not None and self.membership.task == task:
                to = self.membership.leader
            out += box.due(to, now, self.o.report_resend)
            if box.idle and task not in (self.lead and self.lead.task, self.membership and self.membership.task,
                                         self.carrying):
                del self.outboxes[task]
        return out

    def _route(self, msgs: list, now: float) -> list:
        """The messages for the wire; those for this robot are handled here (broadcasts both)."""
        return route(msgs, self.robot_id, lambda m: self._dispatch(m, now))


_HANDLERS = {
    DrLeaderRequest: DrAgent._on_leader_request, DrBidRequest: DrAgent._on_bid_request, DrBid: DrAgent._on_bid,
    DrAward: DrAgent._on_award, DrRobotAlive: DrAgent._on_robot_alive, DrRefuse: DrAgent._on_refuse,
    DrLeaderAlive: DrAgent._on_leader_alive, DrExitLeader: DrAgent._on_exit, DrSvrSample: DrAgent._on_sample,
    DrSampleRequest: DrAgent._on_sample_request, DrLoad: DrAgent._on_load, DrDeliver: DrAgent._on_deliver,
    DrLedger: DrAgent._on_ledger,
}


def _make(ctx: AgentContext) -> DrAgent:
    return DrAgent(ctx)


DR = Method("dr", "paper 000 Double Round auction (SR, Greedy; M/NM x I/NI): transport tasks by leader-run groups",
            DrOptions, _make, KINDS, WIRE_MESSAGES, str(Path(__file__).with_name("dr.xml")))
