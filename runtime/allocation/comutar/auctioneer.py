"""The auctioneer of CoMutaR's Contract Net (paper 003 Section 2.2, steps 1, 5 and 6), sans-IO.

A task's auctioneer is the robot that took it in from the operator (its origin, ``task_id >> 16``); if that
robot is lost, the lowest-id live robot adopts it (after ``2 * report_period`` of listening to holders'
``CmHold`` reports, so a task already held is not announced twice).

* **Insertion.**  One auction at a time, at least ``insert_interval`` (Delta t) apart: ``CmAnnounce``, bids for
  ``auction_timeout`` seconds.  The paper assumes Delta t between any two insertions; with several robots
  taking tasks in, an auctioneer that hears another's announcement waits until that auction is over plus
  the rest of Delta t (and a random 0-0.5 s, so that two that collided do not collide again), so auctions
  run one after the other fleet-wide and their pre-allocations do not crowd each other out.
* **Winner.**  A task served by one coalition (``avoid_obstacles``) goes to the cheapest bid (ties: fewer
  robots, then the lower robot ids).  A ``surveillance`` task takes every robot that can: each robot's
  cheapest bid, up to the task's ``robots`` (0: all), cheapest first; their waypoints are shared.
* **Award.**  ``CmAward`` broadcast, re-sent to every robot that has not acknowledged each ``resend``
  seconds.  After ``ack_timeout`` the silent robots' part is cancelled (``CmCancel``): for a one-coalition
  task the whole award goes, for a team only their share; a task left with nobody is announced again, with
  no limit on how often: at once after its first unacknowledged award, then after ``retry`` x 2^(k-2) (at
  most ``max_backoff``) times 1-2 at random for the k-th in a row, so that its other tasks get their turn.
* **Unservable.**  Only a *dry* round counts: one that drew no bid and in which no robot reported holding
  the task (a holder of an older award of it can serve it, and is cancelled so that it bids next time).
  A task with ``max_announces`` dry rounds in a row (``retry`` to 2 ``retry`` s apart, at random) is
  reported FAILED with the reason; a round with a bid starts the count again.  Lost awards, acknowledgements
  or cancels therefore never make a task unservable.  A holder that resigns, falls silent for
  ``member_timeout`` or is lost releases its share the same way (RELEASED, then announced again).
* **Done.**  A surveillance task when every waypoint is visited (the agent says so), an avoidance task after
  its duration: DONE, and ``CmDone`` to everyone (again to any holder that reports later).
"""
from __future__ import annotations

import math
import random
from dataclasses import dataclass, field

from runtime.allocation.agent import AWARDED, DONE, FAILED, RELEASED, TaskEvent
from runtime.allocation.comutar.messages import CmAnnounce, CmAward, CmCancel, CmDone, slot_robot

QUEUED, BIDDING, AWARDING, SERVED, FINISHED, UNSERVABLE = "queued", "bidding", "awarding", "served", "done", "failed"
TEAM_KINDS = ("surveillance",)          # kinds served by every robot that can, not one coalition


@dataclass
class Job:
    task: object
    state: str = QUEUED
    attempts: int = 0                      # announcements since it was last served (CmAnnounce.attempt)
    dry: int = 0                           # rounds in a row with no bid and no holder heard: "unservable" at max
    unacked: int = 0                       # awards in a row cancelled for want of acknowledgements (back-off)
    claimed: bool = False                  # a robot reported holding the task during the current round
    not_before: float = 0.0
    adopting: bool = False                 # adopted from a lost auctioneer: listening for holders first
    auction: int = 0
    closes: float = 0.0
    bids: list = field(default_factory=list)
    slots: tuple = ()
    robots: set = field(default_factory=set)
    acked: set = field(default_factory=set)
    heard: dict = field(default_factory=dict)
    awarded_at: float = 0.0
    resent: float = 0.0
    served_at: float = 0.0
    reported: bool = False                 # AWARDED event sent for the current award

    @property
    def team(self) -> bool:
        return self.task.kind in TEAM_KINDS


@dataclass
class AuctioneerStats:
    announced: int = 0
    bids: int = 0
    late: int = 0
    awards: int = 0
    resent: int = 0
    released: int = 0
    adopted: int = 0
    ignored: int = 0


class Auctioneer:
    def __init__(self, agent):
        self.a = agent
        self.me = agent.robot_id
        self.o = agent.options
        self.jobs: dict[int, Job] = {}
        self.finished: dict[int, int] = {}          # task -> its last auction (done here or told so)
        self.failed: set[int] = set()
        self.count = 0
        self.next_insert = -math.inf
        self._synced = -1
        self.rng = random.Random(self.me)            # back-off jitter: seeded, so runs repeat
        self.stats = AuctioneerStats()

    # ------------------------------------------------------------------ which tasks are mine
    def sync(self, now: float) -> None:
        """Take the open tasks I am the auctioneer of; let go of those I no longer am (their origin is back)."""
        if self._synced == self.a.fleet_version:
            return
        self._synced = self.a.fleet_version
        for tid, task in self.a.tasks.items():
            if tid in self.jobs or tid in self.finished or tid in self.failed:
                continue
            if self.a.auctioneer_of(tid) == self.me:
                job = Job(task)
                if task.id >> 16 != self.me:
                    job.adopting, job.not_before = True, now + 2 * self.o.report_period
                    self.stats.adopted += 1
                    self.a.log.info("adopting task %d: its auctioneer %d is lost", tid, task.id >> 16)
                self.jobs[tid] = job
        for tid in [t for t in self.jobs if self.a.auctioneer_of(t) != self.me]:
            del self.jobs[tid]

    @property
    def busy(self) -> bool:
        return any(j.state in (BIDDING, AWARDING) or (j.state == QUEUED) for j in self.jobs.values())

    # ------------------------------------------------------------------ each tick
    def tick(self, now: float) -> list:
        self.sync(now)
        out = []
        for job in list(self.jobs.values()):
            if job.state == AWARDING:
                out += self._chase(job, now)
            elif job.state == SERVED:
                out += self._watch(job, now)
            elif job.state == BIDDING and now >= job.closes:
                out += self._close(job, now)
        if not any(j.state == BIDDING for j in self.jobs.values()) and now >= self.next_insert:
            ready = [j for j in self.jobs.values() if j.state == QUEUED and now >= j.not_before]
            if ready:
                out += self._announce(min(ready, key=lambda j: j.task.id), now)
        return out

    def _announce(self, job: Job, now: float) -> list:
        job.adopting = False
        self.count = self.count % 0xFFFF + 1
        job.auction = self.me << 16 | self.count
        job.attempts += 1
        job.state, job.closes, job.bids, job.claimed = BIDDING, now + self.o.auction_timeout, [], False
        self.next_insert = now + self.o.insert_interval
        self.stats.announced += 1
        self.a.log.info("auction %s: task %d (%s), attempt %d", _name(job.auction), job.task.id, job.task.kind,
                        job.attempts)
        return [CmAnnounce(self.me, 0, job.auction, job.task.id, self.o.auction_timeout, job.attempts)]

    def _close(self, job: Job, now: float) -> list:
        live = [b for b in job.bids if all(self.a.is_live(slot_robot(r)) for r in b.slots)]
        slots = self._winners(job, live)
        if not slots:
            return self._no_bids(job, now)
        job.state, job.slots, job.dry = AWARDING, slots, 0
        job.robots = {slot_robot(r) for r in slots}
        job.acked, job.heard = set(), {r: now for r in job.robots}
        job.awarded_at = job.resent = now
        job.reported = False
        self.stats.awards += 1
        self.a.log.info("auction %s: task %d to robots %s (%d bids)", _name(job.auction), job.task.id,
                        sorted(job.robots), len(live))
        return [CmAward(self.me, 0, job.auction, job.task.id, slots)]

    def _winners(self, job: Job, bids) -> tuple[int, ...]:
        if not bids:
            return ()
        order = sorted(bids, key=lambda b: (b.cost, len({slot_robot(r) for r in b.slots}),
                                            sorted({slot_robot(r) for r in b.slots}), b.slots))
        if not job.team:
            return tuple(order[0].slots)
        cap = getattr(job.task.spec, "robots", 0) or 250
        chosen, used, leaders = [], set(), set()
        for b in order:
            if b.sender in leaders or used & set(b.slots) or len(used) + len(b.slots) > 48:
                continue
            chosen.extend(b.slots)
            used |= set(b.slots)
            leaders.add(b.sender)
            if len(leaders) >= cap:
                break
        return tuple(chosen)

    def _no_bids(self, job: Job, now: float) -> list:
        if not job.claimed:
            job.dry += 1
        if job.dry >= self.o.max_announces:
            job.state = UNSERVABLE
            self.failed.add(job.task.id)
            del self.jobs[job.task.id]
            why = (f"unservable: no coalition of actions bid for this {job.task.kind} task in {job.dry} "
                   f"announcements in a row (no robot has the actions, or their resources do not fit)")
            self.a.log.warning("task %d %s", job.task.id, why)
            self.a.events.append(TaskEvent(job.task.id, FAILED, (self.me,), why))
            return []
        wait = self.o.retry * (1.0 + self.rng.random())
        job.state, job.not_before = QUEUED, now + wait
        self.a.log.info("auction %s: no bids for task %d%s; announcing again in %.1f s", _name(job.auction),
                        job.task.id, " (a robot still holds an older award of it)" if job.claimed else "", wait)
        return []

    def _chase(self, job: Job, now: float) -> list:
        silent = job.robots - job.acked
        if now - job.awarded_at >= self.o.ack_timeout:
            why = f"robots {sorted(silent)} did not acknowledge in {self.o.ack_timeout:g} s"
            return self._drop(job, silent, now, why, unacked=True)
        if now - job.resent >= self.o.resend:
            job.resent = now
            self.stats.resent += len(silent)
            return [CmAward(self.me, r, job.auction, job.task.id, job.slots) for r in sorted(silent)]
        return []

    def _watch(self, job: Job, now: float) -> list:
        quiet = {r for r in job.robots if now - job.heard.get(r, now) > self.o.member_timeout}
        if quiet:
            return self._drop(job, quiet, now, f"robots {sorted(quiet)} silent for {self.o.member_timeout:g} s")
        duration = getattr(job.task.spec, "duration", 0.0)
        if job.task.kind == "avoid_obstacles" and duration and now - job.served_at >= duration:
            return self.complete(job.task.id, now)
        return []

    def _served(self, job: Job, now: float) -> None:
        job.state, job.served_at, job.attempts, job.dry, job.unacked = SERVED, now, 0, 0, 0
        if not job.reported:
            job.reported = True
            self.a.events.append(TaskEvent(job.task.id, AWARDED, tuple(sorted(job.robots)),
                                           f"auction {_name(job.auction)}"))

    def _drop(self, job: Job, robots: set, now: float, why: str, unacked: bool = False) -> list:
        """Take ``robots``' share of the award back; a task left with nobody (or a one-coalition task) is
        announced again (after a back-off if ``unacked``: its award went unacknowledged)."""
        if not robots:
            self._served(job, now)
            return []
        whole = not job.team or not (job.robots - robots)
        gone = job.robots if whole else robots
        out = [CmCancel(self.me, r, job.auction, job.task.id) for r in sorted(gone) if self.a.is_live(r)]
        self.stats.released += 1
        self.a.log.warning("task %d: %s; releasing %s", job.task.id, why, sorted(gone))
        self.a.events.append(TaskEvent(job.task.id, RELEASED, tuple(sorted(gone)), why))
        if whole:
            job.not_before = now + self._backoff(job) if unacked else now
            job.state, job.robots, job.slots = QUEUED, set(), ()
            return out
        job.robots -= robots
        job.slots = tuple(r for r in job.slots if slot_robot(r) not in robots)
        if job.state == AWARDING and job.acked >= job.robots:
            self._served(job, now)
        return out

    def _backoff(self, job: Job) -> float:
        """Seconds before announcing again a task whose award went unacknowledged: none the first time, then
        ``retry`` doubling per award lost in a row, at most ``max_backoff``, times 1-2 at random."""
        job.unacked += 1
        if job.unacked == 1:
            return 0.0
        return min(self.o.retry * 2.0 ** (job.unacked - 2), self.o.max_backoff) * (1.0 + self.rng.random())

    def complete(self, task_id: int, now: float) -> list:
        job = self.jobs.pop(task_id, None)
        if job is None:
            return []
        self.finished[task_id] = job.auction
        self.a.log.info("task %d done by robots %s", task_id, sorted(job.robots))
        self.a.events.append(TaskEvent(task_id, DONE, tuple(sorted(job.robots))))
        return [CmDone(self.me, 0, job.auction, task_id)]

    # ------------------------------------------------------------------ messages
    def on_announce(self, m, now: float) -> None:
        """Another auctioneer's auction runs: mine waits until it is over, plus the rest of Delta t."""
        if m.sender != self.me:
            rest = max(0.0, self.o.insert_interval - self.o.auction_timeout)
            self.next_insert = max(self.next_insert, now + m.timeout + rest + 0.5 * self.rng.random())

    def _job(self, m) -> Job | None:
        job = self.jobs.get(m.task)
        return job if job is not None and job.auction == m.auction else None

    def on_bid(self, m, now: float) -> None:
        job = self._job(m)
        if job is None or job.state != BIDDING:
            self.stats.late += 1
            return
        self.stats.bids += 1
        job.bids.append(m)

    def on_ack(self, m, now: float) -> list:
        job = self._job(m)
        if job is None or m.sender not in job.robots:
            self.stats.ignored += 1
            return []
        job.acked.add(m.sender)
        job.heard[m.sender] = now
        if job.state == AWARDING and job.acked >= job.robots:
            self._served(job, now)
        return []

    def on_resign(self, m, now: float) -> list:
        job = self._job(m)
        if job is None or m.sender not in job.robots or job.state not in (AWARDING, SERVED):
            self.stats.ignored += 1
            return []
        return self._drop(job, {m.sender}, now, f"robot {m.sender} resigned")

    def on_hold(self, m, now: float) -> list:
        if m.task in self.finished:
            return [CmDone(self.me, m.sender, self.finished[m.task], m.task)]
        job = self.jobs.get(m.task)
        if job is None:
            self.stats.ignored += 1             # not mine (my view of who is the auctioneer may lag)
            return []
        if job.auction == m.auction and m.sender in job.robots and job.state in (AWARDING, SERVED):
            job.heard[m.sender] = now
            job.acked.add(m.sender)
            if job.state == AWARDING and job.acked >= job.robots:
                self._served(job, now)
            return []
        if job.adopting and job.state == QUEUED or (job.state == SERVED and job.auction == m.auction):
            return self._adopt(job, m, now)
        job.claimed = True                      # it holds an older award: it can serve, once cancelled
        return [CmCancel(self.me, m.sender, m.auction, m.task)]

    def _adopt(self, job: Job, m, now: float) -> list:
        """Rebuild an award from a holder's report (I took the task over from a lost auctioneer)."""
        if job.state == QUEUED:
            job.auction, job.slots, job.robots, job.acked, job.heard = m.auction, (), set(), set(), {}
            job.reported = True                 # the award was reported by its first auctioneer
        job.slots = tuple(dict.fromkeys(job.slots + tuple(m.slots)))
        job.robots.add(m.sender)
        job.acked.add(m.sender)
        job.heard[m.sender] = now
        job.state, job.served_at = SERVED, now
        self.a.log.info("task %d: robot %d holds it under auction %s: adopted", m.task, m.sender, _name(m.auction))
        return []

    def on_done(self, m, now: float) -> None:
        """Another auctioneer completed ``m.task`` (roles changed hands): never announce it again.  Only from the
        robot that is the task's auctioneer now as far as I know (never me: I would know), so a CmDone forged in
        an unsigned fleet cannot end my job."""
        if m.sender != self.me and m.sender == self.a.auctioneer_of(m.task):
            self.jobs.pop(m.task, None)
            self.finished.setdefault(m.task, m.auction)

    # ------------------------------------------------------------------ fleet changes
    def on_peer_lost(self, rid: int, now: float) -> list:
        out = []
        for job in list(self.jobs.values()):
            if job.state in (AWARDING, SERVED) and rid in job.robots:
                out += self._drop(job, {rid}, now, f"robot {rid} lost")
        return out

    def withdraw(self, task_ids) -> None:
        for t in task_ids:
            self.jobs.pop(t, None)


def _name(auction: int) -> str:
    return f"{auction >> 16}.{auction & 0xFFFF}"
