"""How a robot proposes coalitions for the tasks of a round, and what they are worth (paper 001, Table 1
step 2; the paper's ASyMTRe-D becomes a plain travel model here).

* **Who leads what.**  A coalition is proposed by its lowest-id member, the *leader*, so every possible
  coalition has exactly one proposer and no two robots send the same bid.  For a task needing k robots a
  leader picks k - 1 partners among the robots invited to the round with higher ids than its own.
* **How many.**  The leader scores every choice of partners among the ``k - 1 + max_candidates`` nearest
  ones and bids the ``max_candidates`` best.  The best coalition of all for a task is always bid (its
  lowest member proposes it).
* **What a coalition is worth.**  ``value - k * max(travel)``: the task's value less the robot-time the
  coalition spends before it meets, in metres at cruise speed.  Members wait at the point for the slowest,
  so each of the k members is tied up for the slowest member's travel.  Coalitions worth 0 or less are
  not bid: doing the task costs the fleet more than it gains.
* **Travel.**  The leader's own travel is its estimator's (its planner from its pose).  A partner's travel
  is priced by the leader from the partner's reported position (``RobotState``): with the leader's own
  planner on the same map when its estimator has one (``estimator.planner.costs``), else the straight
  line.
"""
from __future__ import annotations

import itertools
import math
from typing import Mapping, Sequence

from runtime.tasks import Task


def own_pose(estimator) -> tuple[float, float] | None:
    """This robot's position from its estimator (``estimator.pose()``), if it has one."""
    pose = getattr(estimator, "pose", None)
    p = pose() if callable(pose) else None
    return None if p is None else (float(p[0]), float(p[1]))


def travel_from(estimator, start: tuple[float, float], points: Sequence[tuple[float, float]]) -> list[float]:
    """Metres of travel from ``start`` to each point, with this robot's planner if its estimator has one."""
    planner = getattr(estimator, "planner", None)
    if planner is not None and hasattr(planner, "costs"):
        return [float(c) for c in planner.costs(start, list(points))]
    return [math.hypot(x - start[0], y - start[1]) for x, y in points]


def value_of(task: Task, travels: Sequence[float]) -> float:
    """A coalition's contribution value for ``task``: its value less k times the slowest member's travel."""
    worst = max(travels)
    return float(task.spec.value) - len(travels) * worst if math.isfinite(worst) else -math.inf


def propose(me: int, task: Task, my_travel: float, partners: Mapping[int, float],
            max_candidates: int) -> list[tuple[tuple[int, ...], float]]:
    """The coalitions ``me`` leads for ``task``: up to ``max_candidates`` (robots, value), best first, value > 0.
    ``partners``: robot id -> travel to the task for the invited robots ``me`` may lead (ids above ``me``)."""
    k = int(task.spec.robots)
    if not math.isfinite(my_travel):
        return []
    pool = sorted((d, r) for r, d in partners.items() if r > me and math.isfinite(d))
    if len(pool) < k - 1:
        return []
    near = pool[:k - 1 + max_candidates]
    scored = []
    for combo in itertools.combinations(near, k - 1):
        travels = [my_travel] + [d for d, _ in combo]
        v = value_of(task, travels)
        if v > 0:
            robots = tuple(sorted([me] + [r for _, r in combo]))
            scored.append((-v, sum(travels), robots))
    scored.sort()
    return [(robots, -nv) for nv, _, robots in scored[:max_candidates]]
