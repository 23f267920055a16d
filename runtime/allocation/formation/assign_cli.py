"""`mrta assign PROBLEM.json`: solve one formation assignment with a chosen method.

PROBLEM.json is either ``{"costs": [[c_robot_task, ...], ...]}`` (square, finite, non-negative) or
``{"robots": [[x, y], ...], "tasks": [[x, y], ...]}`` with optional ``"world": "configs/worlds/x.yaml"``
(then costs are planner path lengths from ``runtime.planning.costs.cost_matrix``, else straight lines).
The distributed methods run on the in-memory bus (:func:`runtime.allocation.formation.simulate.solve`).
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from runtime import argcheck
from runtime.allocation.formation.assignment import check_costs, hungarian, percent_error, straight_line_costs
from runtime.allocation.formation.simulate import METHODS    # the registry's formation solvers, and hungarian
from runtime.errors import InputError
from runtime.jsonfile import read_json

MAX_COORD = 1e9          # m: |x|, |y| of a position (distances and their sums stay far from overflow)
MAX_COST = 1e30          # a cost (the agents' bids and prices travel as MAVLink floats, at most 3.4e38)
MAX_AGENTS = 250         # robots a distributed method can run: MAVLink system ids 1..250
MAX_POINTS = 4000        # robots (= tasks) given as positions: the cost matrix is n x n
MAX_BID_TIMEOUT = 3600.0  # sim s: --bid-timeout (an agent waiting longer for bids has lost its peers)


def _finite(v) -> bool:
    try:
        return math.isfinite(v)
    except OverflowError:          # an integer too large for a float
        return False


def _points(data: dict, key: str, path: Path) -> list[tuple[float, float]]:
    pts = data.get(key)
    if not isinstance(pts, list) or not pts:
        raise InputError(f"{path}: {key}: expected a non-empty list of [x, y] points")
    out = []
    for i, p in enumerate(pts):
        if (not isinstance(p, list) or len(p) != 2
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in p)):
            raise InputError(f"{path}: {key}[{i}]: expected [x, y] (two numbers), got {json.dumps(p)[:40]}")
        if not all(_finite(v) and abs(v) <= MAX_COORD for v in p):
            raise InputError(f"{path}: {key}[{i}]: expected finite coordinates within +-{MAX_COORD:g} m, "
                             f"got {json.dumps(p)[:60]}")
        out.append((float(p[0]), float(p[1])))
    return out


def _world_costs(world: str, robots, tasks, path: Path) -> np.ndarray:
    from runtime import config as C
    from runtime.planning.costs import cost_matrix       # written alongside; imported only when needed

    where = Path(world)
    if not where.is_absolute() and not where.exists() and (path.parent / where).exists():
        where = path.parent / where
    costs = cost_matrix(C.load_world(where), robots, tasks)
    bad = np.argwhere(~np.isfinite(costs))
    if len(bad):
        r, t = (int(v) for v in bad[0])
        raise InputError(f"{path}: robot {r} cannot reach task {t} in world {world} (no path)")
    return costs


def load_problem(path: str | Path) -> tuple[np.ndarray, list | None, list | None]:
    """(costs, robot positions or None, task positions or None) from a problem file, or InputError."""
    path = Path(path)
    data = read_json(path, "problem file")
    if not isinstance(data, dict):
        raise InputError(f'{path}: expected a JSON object with "costs" or "robots" and "tasks"')
    if "costs" in data:
        try:
            costs = check_costs(data["costs"])
        except ValueError as exc:
            raise InputError(f"{path}: {exc}") from None
        if costs.max() > MAX_COST:
            i, j = (int(v) for v in np.unravel_index(np.argmax(costs), costs.shape))
            raise InputError(f"{path}: costs[{i}][{j}]: expected at most {MAX_COST:g}, got {costs[i, j]:g}")
        return costs, None, None
    if "robots" not in data or "tasks" not in data:
        missing = "tasks" if "robots" in data else "robots"
        raise InputError(f'{path}: missing key "{missing}" (expected "costs", or "robots" and "tasks")')
    robots, tasks = _points(data, "robots", path), _points(data, "tasks", path)
    if len(robots) != len(tasks):
        raise InputError(f"{path}: expected as many tasks as robots, got {len(robots)} robots and {len(tasks)} tasks")
    if len(robots) > MAX_POINTS:
        raise InputError(f"{path}: expected at most {MAX_POINTS} robots and tasks (an n x n cost matrix), "
                         f"got {len(robots)}")
    world = data.get("world")
    if world is None:
        costs = straight_line_costs(robots, tasks)
    elif not isinstance(world, str) or not world:
        raise InputError(f"{path}: world: expected a path to a world YAML file")
    else:
        costs = _world_costs(world, robots, tasks, path)
    return costs, robots, tasks


def run(args: argparse.Namespace) -> int:
    from runtime.allocation.formation.simulate import solve

    argcheck.number(args.bid_timeout, "--bid-timeout", 0, MAX_BID_TIMEOUT, lo_open=True)
    costs, robots, tasks = load_problem(args.problem)
    if args.method != "hungarian" and len(costs) > MAX_AGENTS:
        raise InputError(f"{args.problem}: expected at most {MAX_AGENTS} robots for --method {args.method} (one "
                         f"MAVLink system id each; hungarian takes any number), got {len(costs)}")
    result = solve(args.method, costs, tasks=tasks, bid_timeout=args.bid_timeout)
    if args.json:
        print(json.dumps({"assignment": result.assignment, "cost": result.cost, "messages": result.messages}))
        return 0
    _, optimum = hungarian(costs)
    print(f"method {args.method}: {len(costs)} robots, {result.messages} messages, {result.rounds} rounds, "
          f"{result.sim_time:.2f} s simulated{'' if result.converged else ', NOT converged'}")
    print(f"{'robot':>5}  {'task':>4}  {'cost':>10}")
    for r, t in enumerate(result.assignment):
        print(f"{r:>5}  {t:>4}  {costs[r, t] if t >= 0 else math.nan:>10.3f}")
    print(f"total {result.cost:.3f}   optimum {optimum:.3f}   error {percent_error(result.cost, optimum):.2f} %")
    return 0 if result.converged else 1


def register(subparsers) -> None:
    p = subparsers.add_parser("assign", help="assign robots to formation positions (paper 002)",
                              description="Solve one formation assignment (robots to positions) with a chosen method.")
    p.add_argument("problem", help='JSON: {"costs": [[...]]} or {"robots": [[x, y]], "tasks": [[x, y]], "world"?}')
    p.add_argument("--method", choices=METHODS, default="auction",
                   help="auction (epsilon-scaling, exact; default), bs, rtma, or hungarian (centralised)")
    p.add_argument("--bid-timeout", type=float, default=1.0,
                   help=f"agents' bid timeout in sim seconds (0 < S <= {MAX_BID_TIMEOUT:g}, default 1)")
    p.add_argument("--json", action="store_true", help='print {"assignment", "cost", "messages"} as JSON')
    p.set_defaults(func=run)
