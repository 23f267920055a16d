"""The member role of the coalition agent: every robot bids, accepts awards, meets its partners and reports.

* **Bids.**  Offers of a round are collected as they arrive and answered together on the next tick: one
  estimator batch for all the round's tasks, then the coalitions this robot leads
  (:func:`~runtime.allocation.coalition.proposals.propose`), one ``CoalitionBid`` each.  Only a free robot
  the offer invites bids, and only to the robot it believes is the auctioneer.
* **Awards.**  A free robot accepts an award from the auctioneer for a task in its table (``AwardAck``)
  and commits: its commitment is the task with the point moved to its slot on the meeting ring
  (:mod:`~runtime.allocation.coalition.meeting`), its partners and role ``slot i/k``.  Otherwise it
  declines (``AwardCancel``).  A duplicated award is acknowledged again.
* **Reports.**  While committed it sends ``MemberReport`` (coalition, arrived) to the current auctioneer at
  once on arrival or when the auctioneer changes, and every ``report_period``.
* **The end.**  ``CoalitionDone``, an ``AwardCancel`` from the auctioneer, or the task leaving the table
  ends the commitment.  Disarmed or failed, it leaves the coalition with an ``AwardCancel`` of its own.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from runtime.allocation.coalition import meeting
from runtime.allocation.coalition.proposals import propose, travel_from
from runtime.allocation.coalition.wdp_messages import AwardAck, AwardCancel, CoalitionBid, MemberReport
from runtime.tasks import ARRIVED, FAILED, Commitment, Progress, Task

SAME_POSITION = 1e-3        # m: an offer's position (float32 on the wire) and the table's agree within this


@dataclass
class Job:
    round: int
    task: int
    robots: tuple[int, ...]
    auctioneer: int
    commitment: Commitment
    arrived: bool = False
    reported_to: int | None = None
    next_report: float = -math.inf


@dataclass
class MemberStats:
    bids: int = 0
    accepted: int = 0
    declined: int = 0
    ignored: int = 0         # offers from a robot that is not the auctioneer or of no open task, stale cancels
    contradicting: int = 0   # offers placing a task elsewhere than the fleet table


class Member:
    def __init__(self, robot_id: int, view, options, estimator, log):
        self.robot_id = robot_id
        self.view = view
        self.o = options
        self.estimator = estimator
        self.log = log
        self.job: Job | None = None
        self.available = True
        self.localized = True
        self.offers: dict[tuple[int, int], dict[int, object]] = {}     # (auctioneer, round) -> task -> offer
        self.stats = MemberStats()

    @property
    def free(self) -> bool:
        return self.available and self.localized and self.job is None

    @property
    def commitments(self) -> tuple[Commitment, ...]:
        return () if self.job is None else (self.job.commitment,)

    # ------------------------------------------------------------------ bidding
    def on_offer(self, m, now: float) -> None:
        task = self.view.tasks.get(m.task)
        if m.sender != self.view.auctioneer() or task is None:
            self.stats.ignored += 1            # not the auctioneer, or no open task in my table
            return
        if math.dist(task.position, (m.x, m.y)) > SAME_POSITION:
            self.stats.contradicting += 1      # the offer places the task elsewhere than the fleet table
            return
        self.offers.setdefault((m.sender, m.round), {})[m.task] = m

    def bids(self, now: float) -> list:
        out = []
        offers, self.offers = self.offers, {}
        for (auctioneer, rid), by_task in sorted(offers.items()):
            if not self.free or auctioneer != self.view.auctioneer():
                continue
            invited = next(iter(by_task.values())).robots
            if self.robot_id not in invited:
                continue
            out += self._bid(auctioneer, rid, [self.view.tasks[t] for t in sorted(by_task) if t in self.view.tasks],
                             invited)
        self.stats.bids += len(out)
        return out

    def _bid(self, auctioneer: int, rid: int, tasks: list[Task], invited) -> list:
        if not tasks:
            return []
        mine = [e.cost for e in self.estimator.estimates(tasks)]
        points = [t.position for t in tasks]
        partners: dict[int, list[float]] = {}
        if any(t.spec.robots > 1 for t in tasks):
            for r in invited:
                pos = self.view.position(r)
                if r > self.robot_id and self.view.is_live(r) and pos is not None:
                    partners[r] = travel_from(self.estimator, pos, points)
        out = []
        for j, task in enumerate(tasks):
            for robots, value in propose(self.robot_id, task, mine[j], {r: d[j] for r, d in partners.items()},
                                         self.o.max_candidates):
                out.append(CoalitionBid(self.robot_id, auctioneer, rid, task.id, robots, value))
        return out

    # ------------------------------------------------------------------ awards
    def on_award(self, m, now: float) -> list:
        if self.robot_id not in m.robots:
            self.stats.ignored += 1
            return []
        job = self.job
        if job is not None and (job.round, job.task) == (m.round, m.task):
            return [AwardAck(self.robot_id, m.sender, m.round, m.task)]            # a duplicate: ack again
        task = self.view.tasks.get(m.task)
        why = self._refuse(m, task)
        if why is not None:
            self.stats.declined += 1
            self.log.info("declining task %d from robot %d: %s", m.task, m.sender, why)
            return [AwardCancel(self.robot_id, m.sender, m.round, m.task)]
        robots = tuple(m.robots)
        index = robots.index(self.robot_id)
        k = len(robots)
        spot = meeting.slot(task.position, k, index, self.estimator.profile.radius, self.o.spacing)
        commitment = Commitment(Task(task.id, task.kind, dataclasses.replace(task.spec, x=spot[0], y=spot[1])),
                                tuple(r for r in robots if r != self.robot_id), f"slot {index + 1}/{k}")
        self.job = Job(m.round, m.task, robots, m.sender, commitment)
        self.stats.accepted += 1
        self.log.info("committed to task %d with %s: slot %d/%d at (%.2f, %.2f)", m.task,
                      [r for r in robots if r != self.robot_id], index + 1, k, *spot)
        return [AwardAck(self.robot_id, m.sender, m.round, m.task)]

    def _refuse(self, m, task: Task | None) -> str | None:
        """Why this robot cannot take the award ``m``, or None."""
        if self.job is not None:
            return f"busy with task {self.job.task}"
        if not self.free:
            return "disarmed or not localized"
        if task is None:
            return "not an open task in my table"
        if m.sender != self.view.auctioneer():
            return f"robot {self.view.auctioneer()} is the auctioneer"
        if len(m.robots) != task.spec.robots:
            return f"the task needs {task.spec.robots} robots, the award names {len(m.robots)}"
        return None

    def on_cancel(self, m, now: float) -> None:
        job = self.job
        if job is None or (job.round, job.task) != (m.round, m.task):
            return
        if m.sender in (self.view.auctioneer(), job.auctioneer):
            self.log.info("task %d: award withdrawn by robot %d", job.task, m.sender)
            self.job = None

    def on_done(self, m, now: float) -> None:
        job = self.job
        if job is not None and job.task == m.task and m.sender not in (self.view.auctioneer(), job.auctioneer):
            self.stats.ignored += 1            # only an auctioneer ends a coalition
            return
        if self.job is not None and self.job.task == m.task:
            self.log.info("task %d complete: free again", m.task)
            self.job = None

    def withdraw(self, task_ids) -> None:
        if self.job is not None and self.job.task in task_ids:
            self.job = None

    def leave(self, why: str) -> list:
        """Leave my coalition (disarmed, failed): the auctioneer releases it and offers the task again."""
        job, self.job = self.job, None
        if job is None:
            return []
        self.log.warning("leaving the coalition of task %d: %s", job.task, why)
        return [AwardCancel(self.robot_id, self.view.auctioneer(), job.round, job.task)]

    # ------------------------------------------------------------------ execution
    def on_progress(self, p: Progress, now: float) -> list:
        job = self.job
        if job is None or p.task != job.task:
            return []
        if p.event == ARRIVED and not job.arrived:
            job.arrived = True
            job.next_report = -math.inf
        elif p.event == FAILED:
            return self.leave(f"execution failed: {p.detail}")
        return []

    def tick(self, now: float) -> list:
        job = self.job
        if job is None:
            return []
        to = self.view.auctioneer()
        if to == job.reported_to and now < job.next_report:
            return []
        job.reported_to, job.next_report = to, now + self.o.report_period
        return [MemberReport(self.robot_id, to, job.round, job.task, job.robots, job.arrived)]
