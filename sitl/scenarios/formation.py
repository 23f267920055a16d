"""Formation (paper 002): the operator hands the fleet one station-keeping position per robot at t = 0
(MAV_CMD_NAV_LOITER_UNLIM items); the goal is met when every position is held by a distinct live robot
that stands on it."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal, Optional

from runtime.config.build import ConfigError, rng
from runtime.config.world import check_inside


@dataclass(frozen=True)
class Config:
    type: Literal["formation"] = "formation"
    positions: tuple[tuple[float, float], ...] = ()     # m, fleet frame
    to: Optional[int] = None                            # robot the operator uploads to (null: the lowest id)
    tolerance: float = field(default=0.2, metadata=rng(0.01, 10.0))    # m: a robot is on its position

    def check(self, fleet, world, file: str) -> None:
        if not self.positions:
            raise ConfigError(file, "scenario.positions", "at least one position")
        for i, p in enumerate(self.positions):
            check_inside(world, p, file, f"scenario.positions[{i}]")
        if self.to is not None and self.to not in {r.id for r in fleet.robots}:
            raise ConfigError(file, "scenario.to", "the id of a robot of the fleet", self.to)


class Scenario:
    """Hands the positions in as one upload at t = 0; judges and summarises like paper 002's runs."""

    def __init__(self, fleet, world):
        self.cfg: Config = fleet.scenario
        self.fleet = fleet
        self.world = world
        self.positions = [tuple(p) for p in self.cfg.positions]

    def handovers(self) -> list:
        from runtime.comms.mission import MissionItem
        from runtime.tasks.goto import MAV_CMD_NAV_LOITER_UNLIM
        from sitl.scenarios.base import Handover

        to = self.cfg.to if self.cfg.to is not None else min(r.id for r in self.fleet.robots)
        items = [MissionItem(i, 4, MAV_CMD_NAV_LOITER_UNLIM, 0.0, 0.0, 0.0, 0.0, x, y, 0.0)     # MAV_FRAME_LOCAL_ENU
                 for i, (x, y) in enumerate(self.positions)]
        return [Handover(0.0, to, items, [f"P{i}" for i in range(len(items))])]

    def assignment(self, run) -> dict[int, int | None]:
        """Formation index each live robot holds (None: none)."""
        ids = run.handovers[0].task_ids
        index = {tid: i for i, tid in enumerate(ids) if tid is not None}
        out = {}
        for rid in run.robot_ids:
            held = [index[t] for t in run.held(rid) if t in index]
            out[rid] = held[0] if held else None
        return out

    def scene_facts(self, run) -> dict[int, dict]:
        """What the recording's world shows of each target: its label and the live robot standing on it (within
        ``tolerance``), if any."""
        ids = run.handovers[0].task_ids
        live = run.live_robots()
        out = {}
        for i, tid in enumerate(ids):
            if tid is None:
                continue
            px, py = self.positions[i]
            on = next((rid for rid in live
                       if math.hypot(run.true_pose(rid)[0] - px, run.true_pose(rid)[1] - py) <= self.cfg.tolerance),
                      None)
            out[tid] = {"target": f"P{i}", "on": on}
        return out

    def goal(self, run) -> bool:
        return self.shortfall(run) is None

    def shortfall(self, run) -> str | None:
        """What keeps the goal from being met (one line), or None: every position (one per robot of the fleet, as
        far as there are robots) held by a distinct live robot that stands still on it, nobody allocating."""
        if not run.handovers[0].done or None in run.handovers[0].task_ids:
            return "the positions are not all handed in yet"
        live = set(run.live_robots())
        assignment = {rid: t for rid, t in self.assignment(run).items() if rid in live}
        held = [t for t in assignment.values() if t is not None]
        need = min(len(self.positions), len(self.fleet.robots))
        twice = sorted({f"P{t}" for t in held if held.count(t) > 1})
        if twice:
            return f"{', '.join(twice)} held by two robots"
        if len(held) < need:
            free = [f"P{i}" for i in range(len(self.positions)) if i not in held]
            return f"{', '.join(free)} held by no live robot"
        busy = sorted(rid for rid in assignment if not run.settled(rid))
        if busy:
            return "robot(s) " + ", ".join(map(str, busy)) + " still allocating"
        for rid, t in sorted(assignment.items()):
            if t is None:
                continue
            x, y, _ = run.true_pose(rid)
            vx, vy = run.velocity(rid)
            d = math.hypot(self.positions[t][0] - x, self.positions[t][1] - y)
            if d > self.cfg.tolerance:
                return f"robot {rid} is {d:.2f} m from P{t}"
            if math.hypot(vx, vy) > 0.02:
                return f"robot {rid} is still moving on P{t}"
        return None

    def progress(self, run) -> str:
        """The run so far, for the progress line (its tasks are never done: positions are held, then reached)."""
        if not run.handovers[0].done:
            return "positions not handed in yet"
        live = set(run.live_robots())
        assignment = {rid: t for rid, t in self.assignment(run).items() if rid in live and t is not None}
        reached = sum(1 for rid, t in assignment.items()
                      if math.dist(self.positions[t], run.true_pose(rid)[:2]) <= self.cfg.tolerance)
        need = min(len(self.positions), len(self.fleet.robots))
        return f"positions held {len(set(assignment.values()))}/{need}, reached {reached}/{need}"

    def unreachable(self, run) -> str | None:
        """The goal cannot be met any more: robots died, and fewer are left than positions to hold."""
        left = len(self.fleet.robots) - len(run.dead())
        need = min(len(self.positions), len(self.fleet.robots))
        return f"{need} positions to hold and {left} robots left" if left < need else None

    def summary(self, run) -> dict:
        """Assignment, its global cost (planned path lengths from the start poses) beside the Hungarian optimum,
        final errors."""
        from scipy.optimize import linear_sum_assignment

        from runtime.planning.costs import cost_matrix

        starts = {r.id: r.start for r in self.fleet.robots}
        ids = sorted(starts)
        cost = cost_matrix(self.world, [starts[i][:2] for i in ids], self.positions, planner="astar")
        rows, cols = linear_sum_assignment(cost)
        optimum = float(cost[rows, cols].sum())
        assignment = self.assignment(run)
        held = [assignment.get(i) for i in ids]
        n = min(len(ids), len(self.positions))
        taken = [t for t in held if t is not None]
        valid = len(taken) == n and len(set(taken)) == len(taken)
        total = float(sum(cost[k, t] for k, t in enumerate(held) if t is not None)) if valid else math.nan
        errors = {}
        for rid, t in zip(ids, held):
            x, y, _ = run.true_pose(rid)
            errors[rid] = math.hypot(self.positions[t][0] - x, self.positions[t][1] - y) if t is not None else math.nan
        return {"assignment": dict(zip(ids, held)), "valid": valid, "tasks": self.positions,
                "global_cost": total, "optimum": optimum,
                "optimal_assignment": {ids[r]: int(c) for r, c in zip(rows, cols)},
                "final_error": errors}

    @staticmethod
    def print_summary(res: dict, out) -> None:
        print("\nrobot  task  position (m)      optimal task  final error (m)", file=out)
        for rid, task in res["assignment"].items():
            err = res["final_error"][rid]
            pos = "-" if task is None else "({:5.2f}, {:5.2f})".format(*res["tasks"][task])
            opt = res["optimal_assignment"].get(rid, "-")
            held = "lost" if rid in res.get("lost", ()) else ("-" if task is None else task)
            print(f"{rid:5d}  {held:>4}  {pos:16}  {opt:>12}  "
                  f"{'-' if math.isnan(err) else f'{err:.3f}':>15}", file=out)
        if res["valid"]:
            gap = 100.0 * (res["global_cost"] - res["optimum"]) / res["optimum"] if res["optimum"] > 0 else 0.0
            print(f"\nglobal cost (path lengths from the start poses) {res['global_cost']:.3f} m   "
                  f"Hungarian optimum {res['optimum']:.3f} m   "
                  f"gap {gap:+.2f} %", file=out)
        else:
            print(f"\nglobal cost: - (no valid assignment)   Hungarian optimum {res['optimum']:.3f} m", file=out)
        print(f"assignment valid: {res['valid']}   sim time {res['sim_time']:.1f} s", file=out)
