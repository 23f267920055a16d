"""Goal-biased RRT on an occupancy grid (paper 002 Section III: bias probability 0.05).

Each iteration samples the goal with probability ``goal_bias`` (else a uniform point in the grid), extends
the nearest tree node by at most ``step`` metres toward it, and keeps the new node if the segment is
collision-free on the grid.  A goal is reached when a node within ``step`` sees it.  ``rrt_multi`` grows
one tree from a start toward several goals (the bias picks an unreached goal), which is how the bid-cost
provider prices one robot against every task.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from runtime.errors import InputError
from runtime.log import get_logger
from runtime.planning.grid import OccupancyGrid
from runtime.planning.smoothing import path_length, smooth

Point = tuple[float, float]
log = get_logger("planning.rrt")

GOAL_BIAS = 0.05


def _rng(seed) -> np.random.Generator:
    return seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)


def rrt_multi(grid: OccupancyGrid, start: Point, goals: Sequence[Point], step: float | None = None,
              goal_bias: float = GOAL_BIAS, max_iter: int = 20000,
              seed: int | np.random.Generator = 0) -> list[list[Point] | None]:
    """Grow one RRT from ``start``; return, per goal, the raw tree path start..goal, or None if not reached.

    ``step`` defaults to 5 cells.  The tree stops growing once every goal is reached or after ``max_iter``
    iterations.  Start or goal in an occupied cell or outside the grid -> None for it.
    """
    if not 0 <= goal_bias <= 1:
        raise InputError(f"rrt goal_bias: expected a probability in [0, 1], got {goal_bias!r}")
    step = 5 * grid.resolution if step is None else float(step)
    if not (math.isfinite(step) and step > 0):
        raise InputError(f"rrt step: expected a finite number > 0 (m), got {step!r}")
    if not (isinstance(max_iter, int) and max_iter >= 0):
        raise InputError(f"rrt max_iter: expected an integer >= 0, got {max_iter!r}")
    rng = _rng(seed)
    goals = [(float(g[0]), float(g[1])) for g in goals]
    result: list[list[Point] | None] = [None] * len(goals)
    start = (float(start[0]), float(start[1]))
    if not grid.is_free(*start):
        return result
    open_goals = [k for k, g in enumerate(goals) if grid.is_free(*g)]

    nodes = np.empty((max_iter + 1, 2))
    parent = np.empty(max_iter + 1, dtype=np.int64)
    nodes[0], parent[0], n = start, -1, 1

    def branch(k: int, leaf: int) -> list[Point]:
        out = [goals[k]]
        while leaf != -1:
            out.append((float(nodes[leaf, 0]), float(nodes[leaf, 1])))
            leaf = int(parent[leaf])
        out.reverse()
        if len(out) > 1 and out[-2] == out[-1]:
            out.pop()
        return out

    def connect(leaf: int) -> None:
        p = (float(nodes[leaf, 0]), float(nodes[leaf, 1]))
        for k in list(open_goals):
            g = goals[k]
            if math.hypot(g[0] - p[0], g[1] - p[1]) <= step and grid.segment_free(p, g):
                result[k] = branch(k, leaf)
                open_goals.remove(k)

    connect(0)
    (x0, y0), (sx, sy) = grid.origin, grid.size_m
    for _ in range(max_iter):
        if not open_goals:
            break
        if rng.random() < goal_bias:
            target = np.asarray(goals[open_goals[int(rng.integers(len(open_goals)))]])
        else:
            target = np.array([x0 + rng.random() * sx, y0 + rng.random() * sy])
        d2 = np.einsum("ij,ij->i", nodes[:n] - target, nodes[:n] - target)
        near = int(np.argmin(d2))
        dist = math.sqrt(d2[near])
        if dist == 0:
            continue
        new = target if dist <= step else nodes[near] + (target - nodes[near]) * (step / dist)
        a = (float(nodes[near, 0]), float(nodes[near, 1]))
        b = (float(new[0]), float(new[1]))
        if not grid.segment_free(a, b):
            continue
        nodes[n], parent[n] = b, near
        n += 1
        connect(n - 1)
    if open_goals:
        log.debug("rrt: %d of %d goals not reached in %d iterations (%d nodes)",
                  len(open_goals), len(goals), max_iter, n)
    return result


def rrt(grid: OccupancyGrid, start: Point, goal: Point, step: float | None = None,
        goal_bias: float = GOAL_BIAS, max_iter: int = 20000,
        seed: int | np.random.Generator = 0) -> list[Point] | None:
    """Raw RRT path from ``start`` to ``goal`` (tree nodes), or None if not found within ``max_iter``."""
    return rrt_multi(grid, start, [goal], step, goal_bias, max_iter, seed)[0]


def rrt_path(grid: OccupancyGrid, start: Point, goal: Point, seed: int | np.random.Generator = 0,
             **kwargs) -> list[Point] | None:
    """RRT path after shortcut smoothing, or None."""
    raw = rrt(grid, start, goal, seed=seed, **kwargs)
    return None if raw is None else smooth(grid, raw)


def rrt_cost(grid: OccupancyGrid, start: Point, goal: Point, seed: int | np.random.Generator = 0,
             **kwargs) -> float:
    """Path cost as paper 002 uses it: length of the smoothed RRT path (inf if none found)."""
    p = rrt_path(grid, start, goal, seed=seed, **kwargs)
    return math.inf if p is None else path_length(p)
