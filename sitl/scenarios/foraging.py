"""Foraging (paper 000 §6): objects to carry to one delivery point appear at random places, ``present`` at a
time; each is one ``transport`` task handed to the fleet over MAVLink as an operator would, and when the fleet
reports it done a new one appears at once.  The goal is met when ``total`` objects have been delivered.

``kill_leader`` replays the paper's real-robot fault (§6.4): at ``at`` s (or as soon after as the object has a
leader) the daemon of the ``object``-th object's leader dies and (``withdraw``, the default) its body is taken
out of the arena, as the paper's robot was; with ``members: k``, not before the leader's group has k other robots
(the issue's fault: its members leave, one of them or a free robot takes over).  The paper withdrew a leader
that was alone on its object; a new leader then needs a free robot, and with every other robot in a group
until its object is done there is none (the digest's "puzzle"), so a lone leader's successor comes when a
group finishes.  The leader is the robot that announces the
object's group ("task 1.2 awarded to R3+R4": the STATUSTEXT a `dr` leader sends a ground station); the run
then measures how long the object takes to get a new leader (the paper: 15 s) and the goal also requires one
within ``new_leader_within`` s.
"""
from __future__ import annotations

import math
import random
import re
from dataclasses import dataclass, field
from typing import Literal, Optional

from runtime.config.build import ConfigError, rng
from runtime.config.world import check_inside
from runtime.fleet.messages import DONE, STATE_NAMES
from runtime.tasks.transport import Transport, to_item

AWARD_TEXT = re.compile(r"task (\d+)\.(\d+) awarded to ((?:R\d+\+?)*)")


@dataclass(frozen=True)
class KillLeader:
    object: int = field(default=1, metadata=rng(1, 1000))       # the n-th object to appear
    at: float = field(default=20.0, metadata=rng(0.0, None))    # s of sim time, at the earliest
    withdraw: bool = True          # and take its body out of the arena (the paper's robot was carried away)
    members: int = field(default=0, metadata=rng(0, 100))       # once its group has at least this many others


@dataclass(frozen=True)
class Config:
    type: Literal["foraging"] = "foraging"
    present: int = field(default=2, metadata=rng(1, 20))         # objects present at once
    total: int = field(default=2, metadata=rng(1, 10000))        # objects delivered for the goal
    weight: float = field(default=20.0, metadata=rng(0.0, 1e6, lo_open=True))       # wu per object
    deadline: float = field(default=108.0, metadata=rng(0.0, 1e6, lo_open=True))    # s after it appears
    u_max: tuple[float, float] = (50.0, 150.0)                   # utility drawn as an integer in [lo, hi]
    delivery: tuple[float, float] = (0.0, 0.0)                   # m; the robots' allocation.delivery
    min_distance: float = field(default=1.0, metadata=rng(0.0, None))    # m from the delivery point
    margin: float = field(default=0.75, metadata=rng(0.0, None))         # m from the arena's walls
    objects: tuple[tuple[float, float], ...] = ()                # fixed places for the first objects
    to: Optional[int] = None                                     # robot the operator uploads to (null: lowest)
    kill_leader: Optional[KillLeader] = None
    new_leader_within: float = field(default=15.0, metadata=rng(0.0, None, lo_open=True))   # s

    def check(self, fleet, world, file: str) -> None:
        ids = {r.id for r in fleet.robots}
        if self.to is not None and self.to not in ids:
            raise ConfigError(file, "scenario.to", "the id of a robot of the fleet", self.to)
        lo, hi = self.u_max
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo <= hi):
            raise ConfigError(file, "scenario.u_max", "[lo, hi] with 0 <= lo <= hi", self.u_max)
        check_inside(world, self.delivery, file, "scenario.delivery")
        for i, p in enumerate(self.objects):
            check_inside(world, p, file, f"scenario.objects[{i}]")
        sx, sy = world.size
        if min(sx, sy) / 2 - self.margin <= 0 or not _places(world.size, self):
            raise ConfigError(file, "scenario", "room for objects at least min_distance from the delivery point "
                              "and margin from the walls", (self.min_distance, self.margin))
        if self.kill_leader is not None and self.kill_leader.object > self.total + self.present - 1:
            raise ConfigError(file, "scenario.kill_leader.object", f"an object that appears (1..{self.total})",
                              self.kill_leader.object)


def _places(size, cfg: Config, tries: int = 200, seed: int = 0) -> list[tuple[float, float]]:
    """Places an object may appear at: uniform in the arena less ``margin``, at least ``min_distance`` from the
    delivery point (empty when there is no such place)."""
    r = random.Random(seed)
    hx, hy = size[0] / 2 - cfg.margin, size[1] / 2 - cfg.margin
    out = []
    for _ in range(tries):
        p = (r.uniform(-hx, hx), r.uniform(-hy, hy))
        if math.dist(p, cfg.delivery) >= cfg.min_distance:
            out.append(p)
    return out


@dataclass
class Placed:
    """One object: where and what, when it was handed in, its fleet id once known."""
    label: str
    spec: Transport
    handover: object = None
    appeared: float | None = None

    @property
    def task_id(self) -> int | None:
        ids = getattr(self.handover, "task_ids", None)
        return ids[0] if ids else None


class Scenario:
    def __init__(self, fleet, world):
        self.cfg: Config = fleet.scenario
        self.fleet = fleet
        self.world = world
        self.rng = random.Random(f"foraging/{fleet.seed}")
        self.to = self.cfg.to if self.cfg.to is not None else min(r.id for r in fleet.robots)
        self.objects: list[Placed] = []
        self.leaders: dict[int, list[tuple[float, int]]] = {}     # fleet task id -> [(when, leader)]
        self.groups: dict[int, tuple[int, ...]] = {}             # fleet task id -> its leader's last group
        self._texts_seen: set = set()
        self.killed: tuple[float, int, int] | None = None          # (when, robot, task)

    # ------------------------------------------------------------------ objects
    def _new_object(self, at: float):
        from runtime.comms.mission import MissionItem
        from sitl.scenarios.base import Handover

        n = len(self.objects)
        if n < len(self.cfg.objects):
            x, y = self.cfg.objects[n]
        else:
            hx, hy = self.world.size[0] / 2 - self.cfg.margin, self.world.size[1] / 2 - self.cfg.margin
            while True:
                x, y = self.rng.uniform(-hx, hx), self.rng.uniform(-hy, hy)
                if math.dist((x, y), self.cfg.delivery) >= self.cfg.min_distance:
                    break
        lo, hi = self.cfg.u_max
        spec = Transport(round(x, 3), round(y, 3), self.cfg.weight, self.cfg.deadline,
                         float(self.rng.randint(int(math.ceil(lo)), int(math.floor(hi)))) if hi >= math.ceil(lo)
                         else float(lo))
        command, params = to_item(spec)
        label = f"O{n + 1}"
        h = Handover(at, self.to, [MissionItem(0, 4, command, *params, spec.x, spec.y, 0.0)], [label])
        self.objects.append(Placed(label, spec, h, at))
        return h

    def handovers(self) -> list:
        return [self._new_object(0.0) for _ in range(min(self.cfg.present, self.cfg.total))]

    def _done(self, run, o: Placed) -> bool:
        return o.task_id is not None and run.task_state(o.task_id) == DONE

    # ------------------------------------------------------------------ each poll
    def on_poll(self, run, now: float) -> list:
        """New objects for delivered ones, the leaders announced, and the kill when due: what the launcher
        must do (``Handover`` objects and ``("kill", robot)``)."""
        out: list = []
        self._watch_leaders(run)
        present = sum(1 for o in self.objects if not self._done(run, o))
        while present < self.cfg.present and len(self.objects) < self.cfg.total:
            out.append(self._new_object(now))
            present += 1
        k = self.cfg.kill_leader
        if k is not None and self.killed is None and now >= k.at and len(self.objects) >= k.object:
            o = self.objects[k.object - 1]
            tid = o.task_id
            said = self.leaders.get(tid) if tid is not None else None
            members = len(self.groups.get(tid, ())) - 1
            if (said and not self._done(run, o) and said[-1][1] in run.live_robots()
                    and members >= k.members):
                self.killed = (now, said[-1][1], tid)
                out.append(("withdraw" if k.withdraw else "kill", said[-1][1]))
        return out

    def _watch_leaders(self, run) -> None:
        for rid, texts in run.texts().items():
            for t, text in texts:
                key = (rid, t, text)
                if key in self._texts_seen:
                    continue
                self._texts_seen.add(key)
                m = AWARD_TEXT.match(text)
                if m:
                    tid = int(m.group(1)) << 16 | int(m.group(2))
                    self.leaders.setdefault(tid, []).append((t, rid))
                    self.groups[tid] = tuple(int(r) for r in re.findall(r"R(\d+)", m.group(3)))

    def new_leader(self) -> tuple[int, float] | None:
        """After the kill: the object's next leader and how long after the kill it spoke up."""
        if self.killed is None:
            return None
        when, robot, tid = self.killed
        nxt = next(((t, rid) for t, rid in self.leaders.get(tid, []) if t >= when and rid != robot), None)
        return None if nxt is None else (nxt[1], nxt[0] - when)

    # ------------------------------------------------------------------ verdict
    def goal(self, run) -> bool:
        return self.shortfall(run) is None

    def shortfall(self, run) -> str | None:
        done = sum(1 for o in self.objects if self._done(run, o))
        short = []
        if done < self.cfg.total:
            short.append(f"{done}/{self.cfg.total} objects delivered")
        k = self.cfg.kill_leader
        if k is not None:
            if self.killed is None:
                short.append(f"O{k.object}'s leader not killed yet")
            else:
                nl = self.new_leader()
                if nl is None:
                    short.append(f"O{k.object} has no new leader since R{self.killed[1]} was killed")
                elif nl[1] > self.cfg.new_leader_within:
                    short.append(f"O{k.object}'s new leader came {nl[1]:.1f} s after the kill "
                                 f"(> {self.cfg.new_leader_within:g} s)")
        return "; ".join(short) if short else None

    def unreachable(self, run) -> str | None:
        if not run.live_robots() and run.dead():
            return "every robot died"
        return None

    def summary(self, run) -> dict:
        from runtime.allocation.dr.model import utility_soft
        rows = []
        for o in self.objects:
            tid = o.task_id
            done_at = run.done_at.get(tid) if tid is not None else None
            ft = None if done_at is None else done_at - o.appeared
            rows.append({"label": o.label, "task": tid, "x": o.spec.x, "y": o.spec.y, "weight": o.spec.weight,
                         "appeared": o.appeared, "done_at": done_at, "time": ft, "deadline": o.spec.deadline,
                         "in_time": ft is not None and ft < o.spec.deadline, "u_max": o.spec.u_max,
                         "utility": 0.0 if ft is None else utility_soft(ft, o.spec.deadline, o.spec.u_max),
                         "by": run.done_by.get(tid, ()) if tid is not None else (),
                         "state": STATE_NAMES.get(run.task_state(tid), "-") if tid is not None else "not handed in",
                         "leaders": [r for _, r in self.leaders.get(tid, [])] if tid is not None else []})
        done = sum(r["state"] == "done" for r in rows)
        res = {"objects": rows, "done": done, "valid": done >= self.cfg.total, "driven": dict(run.driven)}
        if self.killed is not None:
            when, robot, tid = self.killed
            nl = self.new_leader()
            res["kill"] = {"at": when, "robot": robot, "task": tid,
                           "new_leader": None if nl is None else nl[0], "after": None if nl is None else nl[1]}
        return res

    @staticmethod
    def print_summary(res: dict, out) -> None:
        print("\nobject  position (m)      wu  appeared  done at  time (s)  deadline  in time  utility  by", file=out)
        f = lambda v, w=7, p=1: "-" if v is None else f"{v:{w}.{p}f}"      # noqa: E731
        for r in res["objects"]:
            by = "+".join(f"R{b}" for b in r["by"]) or "-"
            print(f"{r['label']:>6}  ({r['x']:5.2f}, {r['y']:5.2f})  {r['weight']:4g}  {f(r['appeared'], 8)}  "
                  f"{f(r['done_at'])}  {f(r['time'], 8)}  {r['deadline']:8g}  {'yes' if r['in_time'] else 'no':>7}"
                  f"  {r['utility']:7.1f}  {by}", file=out)
        k = res.get("kill")
        if k:
            after = "no new leader" if k["after"] is None else f"new leader R{k['new_leader']} {k['after']:.1f} s later"
            print(f"killed R{k['robot']}, leader of task {k['task'] >> 16}.{k['task'] & 0xFFFF}, at "
                  f"{k['at']:.1f} s: {after}", file=out)
        if res["driven"]:
            print("driven (m): " + ", ".join(f"R{rid} {d:.1f}" for rid, d in sorted(res["driven"].items())), file=out)
        print(f"objects delivered: {res['done']}/{len(res['objects'])}   sim time {res['sim_time']:.1f} s", file=out)
