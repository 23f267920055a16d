"""The SITL's operator: hands the scenario's tasks to the fleet over MAVLink, as a person at a ground station
would, and watches the run through what the robots report.

It owns a :class:`~runtime.comms.gcs.GroundStation` on a port of its own (the fleet's configured
ground-station port stays free for QGC or MAVProxy; the robots stream to the operator too, since it sends
them a GCS HEARTBEAT every second, as a ground station does): each hand-over is one
mission upload (the standard protocol, with its retries and timeouts) to the robot the scenario names, at
its time.  It asks a live robot for the fleet's task table every second, learns which fleet ids the robots
gave the handed-in items, and turns what it sees into the run's trace: tasks awarded (a robot's state
starts naming it), arrived (MISSION_ITEM_REACHED), done (the table says so), robots lost (their state goes
stale or their process dies).  Scenarios judge the run through :class:`RunView`.
"""
from __future__ import annotations

import dataclasses
import math

from runtime.comms.gcs import GroundStation
from runtime.comms.mission import ACCEPTED, result_name
from runtime.messages import ALLOCATING, CLEARED, DONE
from runtime.log import get_logger
from sitl.run_trace import RobotTrack, RunTrace, TaskMark
from sitl.scenarios.base import match_tasks

TABLE_PERIOD = 1.0          # s between table requests
STALE = 3.0                 # s without a RobotState: the robot is not live
RELEASE_GRACE = 2.5         # s a task a robot stopped holding may take to show up done before it counts as released


class Operator:
    def __init__(self, fleet):
        """The operator of ``fleet`` (a launcher Fleet): its scenario's hand-overs, signed with the fleet's key."""
        self.fleet = fleet
        self.scenario = scenario = fleet.scenario
        signing_key = fleet.key
        self.addresses = {rid: ("127.0.0.1", r.udp_port) for rid, r in fleet.robots.items()}
        self.gcs = GroundStation(robots=self.addresses, signing_key=signing_key)
        self.handovers = scenario.handovers()
        self.log = get_logger("sitl.operator")
        world = fleet.world_cfg
        unmapped = tuple(getattr(scenario, "unmapped", ()))      # the scenario's own obstacles, drawn with the map's
        if unmapped:
            world = dataclasses.replace(world, obstacles=tuple(world.obstacles) + unmapped)
        self.trace = RunTrace(world=world, title=f"{fleet.fleet.source}")
        for rid, r in fleet.robots.items():
            self.trace.robots[rid] = RobotTrack(rid, base=r.base_type, radius=r.radius)
        self.dead: set[int] = set()
        self.done_by: dict[int, tuple[int, ...]] = {}
        self.done_at: dict[int, float] = {}
        self.driven: dict[int, float] = {rid: 0.0 for rid in fleet.robots}
        self._started: set[int] = set()              # hand-overs whose upload began
        self._held: dict[int, tuple[int, ...]] = {}
        self._holders: dict[int, tuple[int, ...]] = {}
        self._reached: dict[int, int] = {}
        self._taken: set[int] = set()
        self._dropped: dict[tuple[int, int], float] = {}     # (robot, task) it stopped holding -> when
        self._placeholders = 0
        self._next_table = 0.0
        self._asker = 0
        self.poses: dict[int, tuple[float, float, float]] = {}    # each robot's true pose at posed_at (record)
        self.posed_at: float | None = None
        self.now = 0.0

    # ------------------------------------------------------------------ the loop
    def refused(self) -> list[str]:
        """One line per hand-over the fleet refused (the run cannot meet its goal), with the robot's reason
        (its STATUSTEXT) when it gave one."""
        out = []
        for h in self.handovers:
            if h.done and h.result != ACCEPTED:
                view = self.gcs.robots.get(h.to)
                why = next((text for _, text in reversed(view.texts) if "refused" in text), None) if view else None
                out.append(f"hand-over of {len(h.items)} task(s) at {h.at:g} s to robot {h.to} refused: "
                           f"{why or h.error or result_name(h.result)}")
        return out

    def due(self, now: float) -> bool:
        """A hand-over is due at ``now`` and not finished."""
        return any(h.at <= now and not h.done for h in self.handovers)

    def poll(self, now: float) -> None:
        self.now = now
        gcs = self.gcs
        gcs.poll(now)
        for k, h in enumerate(self.handovers):
            if k in self._started or h.at > now or h.to in gcs.uploads or h.to in self.dead:
                continue
            self._started.add(k)
            up = gcs.upload(h.to, self.addresses[h.to], h.items, now)
            up.handover = h
            for label, it in zip(h.labels, h.items):       # until the robots name it: a placeholder id
                self._placeholders += 1
                self.trace.tasks[self._placeholders] = TaskMark(self._placeholders, "?", it.x, it.y, label, 1, now)
        for up in gcs.finished:
            h = up.handover
            h.done, h.result, h.error = True, up.client.result, up.client.error
            if h.result != ACCEPTED:
                self.log.error("hand-over of %d task(s) to robot %d: %s", len(h.items), h.to,
                               h.error or result_name(h.result))
            self._next_table = now               # ask for the ids at once
        gcs.finished.clear()
        if now >= self._next_table:
            self._next_table = now + TABLE_PERIOD
            live = sorted(self.live_robots()) or sorted(self.fleet.robots)
            rid = live[self._asker % len(live)]
            self._asker += 1
            gcs.request_table(rid, self.addresses[rid])
        for h in self.handovers:
            if h.done and h.result == ACCEPTED and (not h.task_ids or None in h.task_ids):
                for tid in h.task_ids:
                    self._taken.discard(tid)
                match_tasks(h, gcs.table, self._taken)
                self._relabel(h)
        self._events(now)

    def _relabel(self, h) -> None:
        """Trace marks keyed by fleet id once the robots have named the tasks."""
        from runtime import tasks as T
        for label, it, tid in zip(h.labels, h.items, h.task_ids):
            old = next((k for k, m in self.trace.tasks.items() if m.label == label and k < 65536), None)
            if tid is None or old is None:
                continue
            kind = T.kind_of_command(it.command)
            need = int(it.param1) if kind is not None and kind.KIND == "rendezvous" else 1
            arrived = self.trace.tasks.pop(old).arrived_at
            self.trace.tasks[tid] = TaskMark(tid, kind.KIND if kind else "?", it.x, it.y, label, need, arrived)

    def _events(self, now: float) -> None:
        gcs = self.gcs
        for rid, v in gcs.robots.items():
            if rid not in self.fleet.robots:
                continue
            before = self._held.get(rid, ())
            if v.tasks != before:
                for t in before:
                    if t not in v.tasks and t not in self.done_at:
                        self._dropped[(rid, t)] = now
                for t in v.tasks:
                    if t not in before:
                        self.trace.event(now, "awarded", t, (rid,))
                        self._holders[t] = tuple(sorted(set(self._holders.get(t, ())) | {rid}))
                self._held[rid] = v.tasks
            for tid in v.arrived[self._reached.get(rid, 0):]:     # its own arrivals (every robot reports
                self.trace.event(now, "arrived", tid, (rid,))       # every item done as MISSION_ITEM_REACHED)
            self._reached[rid] = len(v.arrived)
        for tid, r in gcs.table.items():
            if tid not in self.trace.tasks:
                self._mark(tid, r, now)
            if r.state in (DONE, CLEARED) and tid not in self.done_at:      # cleared: done, then cleared
                self.done_at[tid] = now
                by = tuple(r.holders) or self._holders.get(tid, ())
                self.done_by[tid] = by
                self.trace.event(now, "done", tid, by)
        for (rid, t), when in list(self._dropped.items()):
            if t in self.done_at and rid in self.done_by[t]:
                del self._dropped[(rid, t)]                     # it let go because it had done it
            elif now - when > RELEASE_GRACE:
                del self._dropped[(rid, t)]
                self.trace.event(when, "released", t, (rid,))

    def _mark(self, tid: int, r, now: float) -> None:
        """A task the operator did not hand in itself (another ground station did): mark it by its fleet id."""
        from runtime import tasks as T
        kind = T.kind_of_command(r.command)
        need = int(r.param1) if kind is not None and kind.KIND == "rendezvous" else 1
        self.trace.tasks[tid] = TaskMark(tid, kind.KIND if kind else "?", r.x, r.y, f"{tid >> 16}.{tid & 0xFFFF}",
                                         need, now)

    def robot_died(self, rid: int, now: float) -> None:
        if rid in self.dead:
            return
        self.dead.add(rid)
        self.trace.robots[rid].lost_at = now
        self.trace.event(now, "lost", None, (rid,))

    def record(self, now: float) -> None:
        """True poses into the trace and the distance driven."""
        for rid in self.fleet.robots:
            if rid in self.fleet.withdrawn:
                continue
            pose = x, y, yaw = self.fleet.true_pose(rid)
            self.trace.robots[rid].add(now, x, y, yaw)
            last = self.poses.get(rid)
            if last is not None:
                self.driven[rid] += math.hypot(x - last[0], y - last[1])
            self.poses[rid] = pose
        self.posed_at = now

    def close(self) -> None:
        self.gcs.close()

    # ------------------------------------------------------------------ what scenarios read
    def live_robots(self) -> list[int]:
        return [rid for rid in self.fleet.robots if rid not in self.dead
                and rid in self.gcs.robots and self.now - self.gcs.robots[rid].heard <= STALE]


class RunView:
    """The run as a scenario judges it: what the operator saw, and the simulator's ground truth."""

    def __init__(self, op: Operator):
        self.op = op
        self.handovers = op.handovers
        self.robot_ids = sorted(op.fleet.robots)
        self.done_by = op.done_by
        self.done_at = op.done_at
        self.driven = op.driven

    def live_robots(self) -> list[int]:
        return self.op.live_robots()

    def dead(self) -> list[int]:
        """Robots whose daemon is known to have ended (its process exited, or a test killed it)."""
        return sorted(self.op.dead)

    def held(self, rid: int) -> tuple[int, ...]:
        if rid not in self.op.live_robots():
            return ()
        return self.op.gcs.robots[rid].tasks

    def settled(self, rid: int) -> bool:
        """Reporting, and not allocating."""
        v = self.op.gcs.robots.get(rid)
        return v is not None and v.state is not None and v.state != ALLOCATING

    def task_state(self, tid: int) -> int | None:
        r = self.op.gcs.table.get(tid)
        return None if r is None else r.state

    def table(self) -> dict:
        """The fleet's tasks as the operator last heard them (fleet id -> TaskRecord)."""
        return dict(self.op.gcs.table)

    def first_seen(self, tid: int) -> float | None:
        mark = self.op.trace.tasks.get(tid)
        return None if mark is None else mark.arrived_at

    def texts(self) -> dict[int, list[tuple[float, str]]]:
        """The STATUSTEXT lines each robot sent the operator, (time heard, line), oldest first (the newest
        few dozen per robot)."""
        return {rid: list(v.texts) for rid, v in self.op.gcs.robots.items() if rid in self.op.fleet.robots}

    def true_pose(self, rid: int):
        return self.op.fleet.true_pose(rid)

    def velocity(self, rid: int):
        return self.op.fleet.robots[rid].body.velocity()
