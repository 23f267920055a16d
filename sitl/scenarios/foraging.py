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

``kill_member`` replays §5.5.3 (robot failure): at ``at`` s (or as soon after as the object's group has a member)
one MEMBER of the ``object``-th object's group (the lowest id other than the leader's) dies and its body is
withdrawn.  The goal then requires its leader to announce a group without it within ``dropped_within`` s of the
kill (the drop: ``member_timeout`` and the ground station's latency) and, unless ``regroup_within`` is null (the
deadline test, eq. 8, still holds after the drop: no new round is due), a group with a robot that was not in it
at the kill within ``regroup_within`` s of the drop (the new auction round).  Whether the object's whole weight
came in is the task's DONE: a dr leader ends a task only when nothing is left at the object or on the way.
"""
from __future__ import annotations

import math
import random
import re
from dataclasses import dataclass, field
from typing import Literal, Optional

from runtime.config.build import ConfigError, rng
from runtime.config.world import check_inside
from runtime.messages import DONE, STATE_NAMES
from runtime.tasks.transport import Transport, to_item
from sitl.foraging.scenario import MIN_DISTANCE

AWARD_TEXT = re.compile(r"task (\d+)\.(\d+) awarded to ((?:R\d+\+?)*)")


@dataclass(frozen=True)
class KillLeader:
    object: int = field(default=1, metadata=rng(1, 1000))       # the n-th object to appear
    at: float = field(default=20.0, metadata=rng(0.0, None))    # s of sim time, at the earliest
    withdraw: bool = True          # and take its body out of the arena (the paper's robot was carried away)
    members: int = field(default=0, metadata=rng(0, 100))       # once its group has at least this many others


@dataclass(frozen=True)
class KillMember:
    object: int = field(default=1, metadata=rng(1, 1000))       # the n-th object to appear
    at: float = field(default=20.0, metadata=rng(0.0, None))    # s of sim time, at the earliest
    withdraw: bool = True          # and take its body out of the arena
    dropped_within: float = field(default=5.0, metadata=rng(0.0, None, lo_open=True))   # s from the kill
    regroup_within: Optional[float] = field(default=10.0, metadata=rng(0.0, None, lo_open=True))   # s from the
    #                              drop to a group with a robot new to it; null: eq. 8 still holds, no round due


@dataclass
class MemberKill:
    """A member killed: when, who, of which task, and the group its leader had named last."""
    at: float
    robot: int
    task: int
    leader: int
    group: tuple[int, ...]


@dataclass(frozen=True)
class Config:
    type: Literal["foraging"] = "foraging"
    present: int = field(default=2, metadata=rng(1, 20))         # objects present at once
    total: int = field(default=2, metadata=rng(1, 10000))        # objects delivered for the goal
    weight: float = field(default=20.0, metadata=rng(0.0, 1e6, lo_open=True))       # wu per object
    deadline: float = field(default=108.0, metadata=rng(0.0, 1e6, lo_open=True))    # s after it appears
    u_max: tuple[float, float] = (50.0, 150.0)                   # utility drawn as an integer in [lo, hi]
    delivery: tuple[float, float] = (0.0, 0.0)                   # m; the robots' allocation.delivery
    min_distance: float = field(default=MIN_DISTANCE, metadata=rng(0.0, None))    # m from the delivery point (1 m
                                                                 # beyond the robots' allocation.delivery_reach)
    margin: float = field(default=0.75, metadata=rng(0.0, None))         # m from the arena's walls
    objects: tuple[tuple[float, float], ...] = ()                # fixed places for the first objects
    to: Optional[int] = None                                     # robot the operator uploads to (null: lowest)
    kill_leader: Optional[KillLeader] = None
    kill_member: Optional[KillMember] = None
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
        for key in ("kill_leader", "kill_member"):
            k = getattr(self, key)
            if k is not None and k.object > self.total + self.present - 1:
                raise ConfigError(file, f"scenario.{key}.object", f"an object that appears (1..{self.total})",
                                  k.object)


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
        self.announced: dict[int, list[tuple[float, int, tuple[int, ...]]]] = {}   # task -> [(when, leader, group)]
        self._texts_seen: set = set()
        self.killed: tuple[float, int, int] | None = None          # (when, robot, task)
        self.member_killed: MemberKill | None = None

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
        out += self._kill_leader(run, now) + self._kill_member(run, now)
        return out

    def _leader_said(self, run, n: int) -> tuple[Placed, int, tuple[int, ...]] | None:
        """The n-th object, its leader and that leader's last group, if it has a live leader and is not done."""
        if len(self.objects) < n:
            return None
        o = self.objects[n - 1]
        tid = o.task_id
        said = self.leaders.get(tid) if tid is not None else None
        if not said or self._done(run, o) or said[-1][1] not in run.live_robots():
            return None
        return o, said[-1][1], self.groups.get(tid, ())

    def _kill_leader(self, run, now: float) -> list:
        k = self.cfg.kill_leader
        if k is None or self.killed is not None or now < k.at:
            return []
        got = self._leader_said(run, k.object)
        if got is None or len(got[2]) - 1 < k.members:
            return []
        o, leader, _ = got
        self.killed = (now, leader, o.task_id)
        return [("withdraw" if k.withdraw else "kill", leader)]

    def _kill_member(self, run, now: float) -> list:
        k = self.cfg.kill_member
        if k is None or self.member_killed is not None or now < k.at:
            return []
        got = self._leader_said(run, k.object)
        live = run.live_robots()
        members = [] if got is None else [r for r in got[2] if r != got[1] and r in live]
        if not members:
            return []
        o, leader, group = got
        self.member_killed = MemberKill(now, min(members), o.task_id, leader, group)
        return [("withdraw" if k.withdraw else "kill", min(members))]

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
                    self.announced.setdefault(tid, []).append((t, rid, self.groups[tid]))

    def new_leader(self) -> tuple[int, float] | None:
        """After the kill: the object's next leader and how long after the kill it spoke up."""
        if self.killed is None:
            return None
        when, robot, tid = self.killed
        nxt = next(((t, rid) for t, rid in self.leaders.get(tid, []) if t >= when and rid != robot), None)
        return None if nxt is None else (nxt[1], nxt[0] - when)

    def member_dropped(self) -> tuple[float, tuple[int, ...]] | None:
        """After a member's kill: how long after it its leader first named a group without it, and that group."""
        k = self.member_killed
        if k is None:
            return None
        for t, rid, group in self.announced.get(k.task, []):
            if t >= k.at and rid == k.leader and k.robot not in group:
                return t - k.at, group
        return None

    def regrouped(self) -> tuple[float, tuple[int, ...]] | None:
        """After the drop: how long after it the leader first named a group with a robot that was not in the group
        at the kill (a new auction round's award), and that group."""
        k, drop = self.member_killed, self.member_dropped()
        if k is None or drop is None:
            return None
        dropped_at = k.at + drop[0]
        for t, rid, group in self.announced.get(k.task, []):
            if t >= dropped_at and rid == k.leader and set(group) - set(k.group):
                return t - dropped_at, group
        return None

    def scene_facts(self, run) -> dict[int, dict]:
        """What the recording's world shows of each object handed in: its label and weight (what is left of it
        and who carries it come from its leader's reports)."""
        return {o.task_id: {"object": o.label, "weight": o.spec.weight} for o in self.objects
                if o.task_id is not None}

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
        short += self._member_shortfall()
        return "; ".join(short) if short else None

    def _member_shortfall(self) -> list[str]:
        k = self.cfg.kill_member
        if k is None:
            return []
        mk = self.member_killed
        if mk is None:
            return [f"no member of O{k.object}'s group killed yet"]
        drop = self.member_dropped()
        if drop is None:
            return [f"O{k.object}'s leader R{mk.leader} has not dropped R{mk.robot} (killed at {mk.at:.1f} s)"]
        short = []
        if drop[0] > k.dropped_within:
            short.append(f"R{mk.leader} dropped R{mk.robot} {drop[0]:.1f} s after the kill (> {k.dropped_within:g} s)")
        if k.regroup_within is not None:
            again = self.regrouped()
            if again is None:
                short.append(f"O{k.object} had no new round after R{mk.robot} was dropped")
            elif again[0] > k.regroup_within:
                short.append(f"O{k.object}'s new round came {again[0]:.1f} s after the drop (> {k.regroup_within:g} s)")
        return short

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
        mk = self.member_killed
        if mk is not None:
            drop, again = self.member_dropped(), self.regrouped()
            res["member_kill"] = {"at": mk.at, "robot": mk.robot, "task": mk.task, "leader": mk.leader,
                                  "group": mk.group,
                                  "dropped_after": drop and drop[0], "dropped_group": drop and drop[1],
                                  "regroup_after": again and again[0], "regroup_group": again and again[1]}
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
        mk = res.get("member_kill")
        if mk:
            plus = lambda g: "+".join(f"R{r}" for r in g)      # noqa: E731
            drop = ("not dropped" if mk["dropped_after"] is None
                    else f"dropped {mk['dropped_after']:.1f} s later ({plus(mk['dropped_group'])})")
            again = ("no new round" if mk["regroup_after"] is None
                     else f"new round {mk['regroup_after']:.1f} s after the drop: {plus(mk['regroup_group'])}")
            print(f"killed R{mk['robot']}, member of task {mk['task'] >> 16}.{mk['task'] & 0xFFFF} "
                  f"(group {plus(mk['group'])}, leader R{mk['leader']}), at {mk['at']:.1f} s: {drop}; {again}",
                  file=out)
        if res["driven"]:
            print("driven (m): " + ", ".join(f"R{rid} {d:.1f}" for rid, d in sorted(res["driven"].items())), file=out)
        print(f"objects delivered: {res['done']}/{len(res['objects'])}   sim time {res['sim_time']:.1f} s", file=out)
