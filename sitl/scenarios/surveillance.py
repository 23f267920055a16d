"""Surveillance with a borrowed sensor (paper 003 §4, Figs. 6-7): one robot with no range sensor surveys a region
among obstacles that are in no robot's map, avoiding them with another robot's sonar; every robot has its own
``avoid_obstacles`` task, handed in with the ``surveillance`` task over MAVLink as an operator would.

``kill_provider``: at ``at`` s (or as soon after as the borrower's avoidance has a provider) the daemon of the
robot whose sensor the borrower uses dies (the robot named in "task a.b awarded to R1+R2", the STATUSTEXT its
auctioneer sends, other than the borrower).  The goal: every waypoint visited (the surveillance task done), the
borrower never within ``clearance`` m of an obstacle (pybullet's closest points between the bodies, every
poll), the borrower standing still within ``stop_within`` s of the kill, and its avoidance awarded again to a
robot other than the killed one within ``reallocate_within`` s.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Literal, Optional

from runtime.tasks import avoid_obstacles as AV
from runtime.tasks import surveillance as SV
from runtime.config.build import ConfigError, rng
from runtime.config.world import check_inside
from runtime.messages import DONE, STATE_NAMES

AWARD_TEXT = re.compile(r"task (\d+)\.(\d+) awarded to ((?:R\d+\+?)*)")
STILL = 0.01                   # m/s: a body slower than this stands still


@dataclass(frozen=True)
class Pillar:
    center: tuple[float, float]
    size: tuple[float, float] = (0.3, 0.3)          # m
    height: float = field(default=0.5, metadata=rng(0.05, 5.0))


@dataclass(frozen=True)
class KillProvider:
    at: float = field(default=30.0, metadata=rng(0.0, None))      # s of sim time, at the earliest


@dataclass(frozen=True)
class Config:
    type: Literal["surveillance"] = "surveillance"
    region: tuple[float, float, float, float] = (0.0, 0.0, 4.0, 4.0)    # m: centre x, y, width, height
    spacing: float = field(default=2.0, metadata=rng(0.1, 100.0))      # m between waypoints
    surveyors: int = field(default=1, metadata=rng(0, 250))            # robots on the survey (0: all that can)
    borrower: int = 1                                                  # the robot with no range sensor
    avoid: tuple[int, ...] = ()                                        # robots given an avoid_obstacles task
    pillars: tuple[Pillar, ...] = ()                                   # unmapped obstacles (in no robot's map)
    to: Optional[int] = None                                           # robot the operator uploads to
    kill_provider: Optional[KillProvider] = None
    clearance: float = field(default=0.0, metadata=rng(0.0, 10.0))     # m the borrower must keep from pillars
    stop_within: float = field(default=1.0, metadata=rng(0.0, 60.0, lo_open=True))         # s
    reallocate_within: float = field(default=15.0, metadata=rng(0.0, 600.0, lo_open=True))  # s

    def check(self, fleet, world, file: str) -> None:
        ids = {r.id for r in fleet.robots}
        for key, rid in [("borrower", self.borrower), ("to", self.to)] + [(f"avoid[{i}]", r)
                                                                          for i, r in enumerate(self.avoid)]:
            if rid is not None and rid not in ids:
                raise ConfigError(file, f"scenario.{key}", "the id of a robot of the fleet", rid)
        x, y, w, h = self.region
        for cx, cy in ((x - w / 2, y - h / 2), (x + w / 2, y + h / 2)):
            check_inside(world, (cx, cy), file, "scenario.region")
        for i, p in enumerate(self.pillars):
            check_inside(world, p.center, file, f"scenario.pillars[{i}]")
        try:
            SV.from_item(SV.MAV_CMD_SPATIAL_USER_1, (w, h, self.spacing, self.surveyors), x, y)
        except ValueError as exc:
            raise ConfigError(file, "scenario.region", f"a region the surveillance task takes ({exc})",
                              self.region) from None


class Scenario:
    def __init__(self, fleet, world):
        self.cfg: Config = fleet.scenario
        self.fleet = fleet
        self.to = self.cfg.to if self.cfg.to is not None else min(r.id for r in fleet.robots)
        x, y, w, h = self.cfg.region
        self.spec = SV.Surveillance(x, y, w, h, self.cfg.spacing, self.cfg.surveyors)
        self.handover = None
        self.pillar_ids: list[int] = []
        self.awards: dict[int, list[tuple[float, tuple[int, ...]]]] = {}    # task -> [(when, robots)]
        self._seen: set = set()
        self.least = math.inf                     # the borrower's least distance to a pillar (m)
        self.least_at: float | None = None        # sim time (s) of that least distance
        self.killed: tuple[float, int] | None = None
        self.stood_still: float | None = None     # s after the kill the borrower stood still
        self.moved_after_stop = 0.0               # m the borrower drove between standing still and re-allocation

    # ------------------------------------------------------------------ world and tasks
    def build(self, world) -> None:
        """The pillars, as unmapped boxes."""
        self.pillar_ids = [world.add_box(p.center, p.size, p.height) for p in self.cfg.pillars]

    @property
    def unmapped(self) -> tuple:
        """The pillars as world boxes (for the run's picture; no robot's map has them)."""
        from runtime.config.world import Box
        return tuple(Box(tuple(p.center), tuple(p.size), p.height) for p in self.cfg.pillars)

    def handovers(self) -> list:
        from runtime.comms.mission import MissionItem
        from sitl.scenarios.base import Handover

        items, labels = [], []
        for rid in self.cfg.avoid:
            command, params = AV.to_item(AV.AvoidObstacles(rid))
            items.append(MissionItem(len(items), 4, command, *params, 0.0, 0.0, 0.0))
            labels.append(f"avoid R{rid}")
        command, params = SV.to_item(self.spec)
        items.append(MissionItem(len(items), 4, command, *params, self.spec.x, self.spec.y, 0.0))
        labels.append("survey")
        self.handover = Handover(0.0, self.to, items, labels)
        return [self.handover]

    def _task(self, label: str) -> int | None:
        h = self.handover
        if h is None or not h.task_ids:
            return None
        return dict(zip(h.labels, h.task_ids)).get(label)

    # ------------------------------------------------------------------ each poll
    def on_poll(self, run, now: float) -> list:
        self._watch(run)
        self._measure(run, now)
        k = self.cfg.kill_provider
        if k is None or self.killed is not None or now < k.at:
            return []
        provider = self.provider()
        if provider is not None and provider in run.live_robots():
            self.killed = (now, provider)
            return [("kill", provider)]
        return []

    def provider(self, since: float = -math.inf) -> int | None:
        """The robot, other than the borrower, in the borrower's avoidance coalition as last awarded (since)."""
        tid = self._task(f"avoid R{self.cfg.borrower}")
        said = [r for t, r in self.awards.get(tid, []) if t >= since] if tid is not None else []
        others = [r for r in (said[-1] if said else ()) if r != self.cfg.borrower]
        return others[0] if others else None

    def _watch(self, run) -> None:
        for rid, texts in run.texts().items():
            for t, text in texts:
                if (rid, t, text) in self._seen:
                    continue
                self._seen.add((rid, t, text))
                m = AWARD_TEXT.match(text)
                if m:
                    tid = int(m.group(1)) << 16 | int(m.group(2))
                    self.awards.setdefault(tid, []).append((t, tuple(int(r) for r in re.findall(r"R(\d+)", m.group(3)))))

    def _measure(self, run, now: float) -> None:
        import pybullet as p

        fleet = run.op.fleet
        body = fleet.robots[self.cfg.borrower].body
        cid = fleet.world.client_id
        for pid in self.pillar_ids:
            for pt in p.getClosestPoints(body.body_id, pid, 1.0, physicsClientId=cid):
                if float(pt[8]) < self.least:
                    self.least, self.least_at = float(pt[8]), now
        if self.killed is not None:
            speed = math.hypot(*run.velocity(self.cfg.borrower)[:2])
            if self.stood_still is None and speed < STILL:
                self.stood_still = now - self.killed[0]
            elif self.stood_still is not None and self.reallocated() is None:
                self.moved_after_stop = max(self.moved_after_stop, speed)

    def reallocated(self) -> tuple[int, float] | None:
        """After the kill: the borrower's next provider and how long after the kill it was awarded."""
        if self.killed is None:
            return None
        when, dead = self.killed
        tid = self._task(f"avoid R{self.cfg.borrower}")
        for t, robots in self.awards.get(tid, []) if tid is not None else []:
            others = [r for r in robots if r not in (dead, self.cfg.borrower)]
            if t > when and others:
                return others[0], t - when
        return None

    # ------------------------------------------------------------------ verdict
    def goal(self, run) -> bool:
        return self.shortfall(run) is None

    def shortfall(self, run) -> str | None:
        short = []
        tid = self._task("survey")
        if tid is None or run.task_state(tid) != DONE:
            short.append("the region is not surveyed yet")
        if self.least <= self.cfg.clearance:
            short.append(self._close_call())
        if self.cfg.kill_provider is not None:
            if self.killed is None:
                short.append("the sensor robot not killed yet")
            else:
                if self.stood_still is None or self.stood_still > self.cfg.stop_within:
                    short.append(f"R{self.cfg.borrower} did not stand still within {self.cfg.stop_within:g} s of the kill")
                re_ = self.reallocated()
                if re_ is None or re_[1] > self.cfg.reallocate_within:
                    short.append(f"R{self.cfg.borrower}'s avoidance not re-allocated within "
                                 f"{self.cfg.reallocate_within:g} s of the kill")
        return "; ".join(short) if short else None

    def unreachable(self, run) -> str | None:
        if self.least <= self.cfg.clearance:
            return self._close_call()
        return None

    def _close_call(self) -> str:
        what = "touched a pillar" if self.least <= 0.0 else f"came within {self.least:.3f} m of a pillar"
        return (f"R{self.cfg.borrower} {what} at {self.least_at:.1f} s (the fleet's scenario.clearance asks for more "
                f"than {self.cfg.clearance:g} m)")

    def summary(self, run) -> dict:
        rows = []
        h = self.handover
        for label, tid in zip(h.labels, h.task_ids or [None] * len(h.labels)) if h else []:
            state = run.task_state(tid) if tid is not None else None
            rows.append({"label": label, "task": tid, "state": STATE_NAMES.get(state, "-"),
                         "awards": [(round(t, 1), "+".join(f"R{r}" for r in rs)) for t, rs in self.awards.get(tid, [])],
                         "done_at": run.done_at.get(tid) if tid is not None else None})
        res = {"tasks": rows, "least_clearance": self.least, "least_clearance_at": self.least_at,
               "driven": dict(run.driven),
               "valid": bool(rows) and rows[-1]["state"] == "done"}
        if self.killed is not None:
            re_ = self.reallocated()
            res["kill"] = {"at": self.killed[0], "robot": self.killed[1], "stood_still_after": self.stood_still,
                           "moved_before_reallocation": self.moved_after_stop,
                           "new_provider": None if re_ is None else re_[0], "after": None if re_ is None else re_[1]}
        return res

    @staticmethod
    def print_summary(res: dict, out) -> None:
        print("\ntask       fleet id  state      done at (s)  awards (s: robots)", file=out)
        for r in res["tasks"]:
            tid = "-" if r["task"] is None else f"{r['task'] >> 16}.{r['task'] & 0xFFFF}"
            done = "-" if r["done_at"] is None else f"{r['done_at']:.1f}"
            aw = ", ".join(f"{t}: {who}" for t, who in r["awards"]) or "-"
            print(f"{r['label']:9}  {tid:>8}  {r['state']:9}  {done:>11}  {aw}", file=out)
        at = res.get("least_clearance_at")
        print(f"least clearance of the borrower to a pillar: {res['least_clearance']:.3f} m"
              + ("" if at is None else f" (at {at:.1f} s)"), file=out)
        k = res.get("kill")
        if k:
            still = "never" if k["stood_still_after"] is None else f"{k['stood_still_after']:.2f} s later"
            new = "none" if k["new_provider"] is None else f"R{k['new_provider']} {k['after']:.1f} s after the kill"
            print(f"killed R{k['robot']} (the borrower's sensor) at {k['at']:.1f} s: borrower still {still}; "
                  f"new provider {new}", file=out)
        if res["driven"]:
            print("driven (m): " + ", ".join(f"R{rid} {d:.1f}" for rid, d in sorted(res["driven"].items())), file=out)
        print(f"sim time {res['sim_time']:.1f} s", file=out)
