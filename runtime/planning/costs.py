"""Bid costs for the auctions: robots x tasks path lengths in metres, and the paths robots drive.

Planners: ``"euclid"`` (straight line, paper 002's obstacle-free runs), ``"astar"`` (shortest path on the
8-connected grid graph, one Dijkstra per robot or task for a whole matrix; a pair with a clear straight
line costs exactly the Euclidean distance) and ``"rrt"`` (goal-biased RRT, length after smoothing).
A point in an occupied (e.g. inflated) cell is snapped to the nearest free cell within ``snap`` metres;
otherwise, or when no path exists, the cost is inf and the path None.
"""
from __future__ import annotations

import functools
import math
from typing import Sequence

import numpy as np
from scipy import ndimage

from runtime.config import WorldConfig
from runtime.errors import InputError
from runtime.planning.astar import astar, cost_table
from runtime.planning.grid import CREATE2_RADIUS, OccupancyGrid
from runtime.planning.rrt import rrt_multi
from runtime.planning.smoothing import path_length, smooth

PLANNERS = ("astar", "rrt", "euclid")
RETRY_SEED = 7919     # an RRT miss grows a second tree with seed + RETRY_SEED ...
RETRY_GROWTH = 4      # ... and RETRY_GROWTH x the iterations, before falling back to A*
Point = tuple[float, float]


def grid_for(world: WorldConfig, inflate: float = CREATE2_RADIUS) -> OccupancyGrid:
    """The inflated occupancy grid of a world config (cached per config and radius, with its graphs)."""
    return _grid_cached(world, float(inflate))


@functools.lru_cache(maxsize=16)
def _grid_cached(world: WorldConfig, inflate: float) -> OccupancyGrid:
    return OccupancyGrid.from_world(world, inflate=inflate)


def _grid(world_or_grid, inflate: float) -> OccupancyGrid:
    if isinstance(world_or_grid, OccupancyGrid):
        return world_or_grid
    if isinstance(world_or_grid, WorldConfig):
        return grid_for(world_or_grid, inflate)
    raise InputError(f"cost provider map: expected a WorldConfig or OccupancyGrid, got {type(world_or_grid).__name__}")


def _points(xy, what: str) -> np.ndarray:
    try:
        a = np.asarray(xy, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{what}: expected a list of (x, y) points in metres") from None
    if a.size == 0:
        return np.zeros((0, 2))
    if a.ndim != 2 or a.shape[1] < 2:
        raise InputError(f"{what}: expected a list of (x, y) points in metres, got shape {a.shape}")
    a = a[:, :2]
    if not np.all(np.isfinite(a)):
        raise InputError(f"{what}: expected finite (x, y) in metres, got NaN or inf")
    return a


def _check_planner(planner: str) -> None:
    if planner not in PLANNERS:
        raise InputError(f"planner: expected one of {', '.join(PLANNERS)}, got {planner!r}")


def _nearest_free(grid: OccupancyGrid) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per cell: distance (m) to the nearest free cell centre and that cell's (iy, ix) (cached)."""
    if "nearest_free" not in grid._cache:
        dist, (iy, ix) = ndimage.distance_transform_edt(grid.occ, sampling=grid.resolution, return_indices=True)
        grid._cache["nearest_free"] = (dist, iy, ix)
    return grid._cache["nearest_free"]


def snap_cells(grid: OccupancyGrid, xy: np.ndarray, snap: float) -> tuple[np.ndarray, np.ndarray]:
    """Cells (ix, iy) for world points: their own cell if free, else the nearest free cell within ``snap``
    metres; (-1, -1) where there is none (outside the grid, or boxed in)."""
    ix, iy = grid.world_to_cell(xy[:, 0], xy[:, 1])
    inside = grid.in_bounds(ix, iy)
    ix, iy = np.where(inside, ix, -1), np.where(inside, iy, -1)
    if grid.occ.any() and grid.occ[iy[inside], ix[inside]].any():
        dist, niy, nix = _nearest_free(grid)
        if np.all(grid.occ):
            return np.full_like(ix, -1), np.full_like(iy, -1)
        for k in np.flatnonzero(inside):
            if grid.occ[iy[k], ix[k]]:
                ok = dist[iy[k], ix[k]] <= snap
                ix[k], iy[k] = (nix[iy[k], ix[k]], niy[iy[k], ix[k]]) if ok else (-1, -1)
    return ix, iy


def cost_matrix(world_or_grid: WorldConfig | OccupancyGrid | None, robots_xy, tasks_xy, planner: str = "astar",
                seed: int = 0, inflate: float = CREATE2_RADIUS, snap: float | None = None,
                rrt_iterations: int = 20000) -> np.ndarray:
    """Bid costs: array (robots x tasks) of path lengths in metres, inf where unreachable.

    ``world_or_grid`` may be None for ``planner="euclid"``.  ``snap`` defaults to inflate + one cell.
    """
    _check_planner(planner)
    robots = _points(robots_xy, "robot positions")
    tasks = _points(tasks_xy, "task positions")
    euclid = np.hypot(robots[:, None, 0] - tasks[None, :, 0], robots[:, None, 1] - tasks[None, :, 1])
    if planner == "euclid" or len(robots) == 0 or len(tasks) == 0:
        return euclid
    grid = _grid(world_or_grid, inflate)
    snap = inflate + grid.resolution if snap is None else snap
    rix, riy = snap_cells(grid, robots, snap)
    tix, tiy = snap_cells(grid, tasks, snap)
    rok, tok = rix >= 0, tix >= 0
    out = np.full(euclid.shape, np.inf)
    if planner == "astar":
        # Robots that see every task along a clear line need no search: their row is the straight-line
        # distance (the daemon refreshes its row while driving; in the open this keeps it off the grid).
        r_all, t_all = np.meshgrid(np.arange(len(robots)), np.arange(len(tasks)), indexing="ij")
        sight = grid.segments_free(robots[r_all.ravel()], tasks[t_all.ravel()]).reshape(euclid.shape)
        seen = sight.all(axis=1) & rok
        out[seen] = euclid[seen]
        search = rok & ~seen
        if search.any() and tok.any():
            table = cost_table(grid, np.column_stack((rix[search], riy[search])),
                               np.column_stack((tix[tok], tiy[tok])))
            out[np.ix_(search, tok)] = table
        # The grid graph overestimates any-angle lengths by up to 8 %: a pair with a clear line costs
        # exactly the straight-line distance, and no path is shorter than it.
        # Only pairs that could have a clear line: along a clear line the grid path is at most the
        # Manhattan distance between the two cells (<= sqrt(2) * Euclid + 2 cells).
        maybe = np.isfinite(out) & (out > euclid) & (out <= math.sqrt(2) * euclid + 2.0001 * grid.resolution)
        r, t = np.nonzero(maybe)
        clear = grid.segments_free(robots[r], tasks[t])
        out[r[clear], t[clear]] = euclid[r[clear], t[clear]]
        return np.maximum(out, euclid)
    rng = np.random.default_rng(seed)
    for r in np.flatnonzero(rok):
        start = grid.cell_to_world(rix[r], riy[r])
        goals = [grid.cell_to_world(tix[t], tiy[t]) for t in np.flatnonzero(tok)]
        paths = rrt_multi(grid, start, goals, max_iter=rrt_iterations, seed=rng)
        for t, p in zip(np.flatnonzero(tok), paths):
            if p is not None:
                full = _with_ends(grid, smooth(grid, p), robots[r], tasks[t])
                out[r, t] = path_length(full)
    return np.maximum(out, euclid)


def bid_costs(world_or_grid: WorldConfig | OccupancyGrid | None, start: Sequence[float], tasks_xy,
              planner: str = "astar", seed: int = 0, inflate: float = CREATE2_RADIUS,
              rrt_iterations: int = 20000) -> tuple[np.ndarray, int]:
    """One robot's bid costs to ``tasks_xy``, priced like the paths :func:`plan_route` gives it, and how many
    tasks needed a fallback.

    With RRT, tasks the tree missed get a second tree (RETRY_SEED, RETRY_GROWTH), then their A* length:
    a robot must not bid "cannot" for a task it can reach, or an auction may have no buyer for it (BS and
    RTMA resell only to a worse bid).  inf only where A* finds no path either (then no second tree is grown:
    the row is refreshed as the robot moves, and a big tree per refresh for a walled-off task would eat the CPU).
    """
    row = cost_matrix(world_or_grid, [start], tasks_xy, planner=planner, seed=seed, inflate=inflate,
                      rrt_iterations=rrt_iterations)[0]
    missed = np.flatnonzero(~np.isfinite(row))
    if planner != "rrt" or missed.size == 0:
        return row, 0
    tasks = _points(tasks_xy, "task positions")
    a_star = cost_matrix(world_or_grid, [start], tasks[missed], planner="astar", inflate=inflate)[0]
    reach = missed[np.isfinite(a_star)]          # no second tree for a task nothing can reach (it is cheap)
    if reach.size:
        row[reach] = cost_matrix(world_or_grid, [start], tasks[reach], planner="rrt", seed=seed + RETRY_SEED,
                                 inflate=inflate, rrt_iterations=RETRY_GROWTH * rrt_iterations)[0]
    row[missed] = np.where(np.isfinite(row[missed]), row[missed], a_star)
    return row, int(missed.size)


def plan_route(world_or_grid: WorldConfig | OccupancyGrid, start: Sequence[float], goal: Sequence[float],
               planner: str = "astar", seed: int = 0, inflate: float = CREATE2_RADIUS,
               rrt_iterations: int = 20000) -> tuple[list[Point] | None, str]:
    """A path for a robot to drive, and the planner that found it.

    RRT is only probabilistically complete: a tree can miss a goal behind a narrow gap, and a robot sent
    straight at it would push into the boxes.  So an RRT miss grows a second tree (RETRY_SEED,
    RETRY_GROWTH), then takes the A* path, which exists whenever the grid connects the two points.
    (None, "") when A* finds none: then no second tree is grown.
    """
    route = path(world_or_grid, start, goal, planner=planner, seed=seed, inflate=inflate,
                 rrt_iterations=rrt_iterations)
    if route is not None or planner != "rrt":
        return route, planner if route is not None else ""
    a_star = path(world_or_grid, start, goal, planner="astar", inflate=inflate)
    if a_star is None:                           # nothing connects them: no second tree to grow
        return None, ""
    route = path(world_or_grid, start, goal, planner="rrt", seed=seed + RETRY_SEED, inflate=inflate,
                 rrt_iterations=RETRY_GROWTH * rrt_iterations)
    return (route, "rrt") if route is not None else (a_star, "astar")


def _with_ends(grid: OccupancyGrid, pts: list[Point], start, goal) -> list[Point]:
    """Replace the snapped end points with the real ones where the straight join is clear, else prepend/append."""
    s, g = (float(start[0]), float(start[1])), (float(goal[0]), float(goal[1]))
    pts = list(pts)
    if len(pts) >= 2 and grid.segment_free(s, pts[1]):
        pts[0] = s
    elif pts[0] != s:
        pts.insert(0, s)
    if len(pts) >= 2 and grid.segment_free(pts[-2], g):
        pts[-1] = g
    elif pts[-1] != g:
        pts.append(g)
    return pts


def path(world_or_grid: WorldConfig | OccupancyGrid, start: Sequence[float], goal: Sequence[float],
         planner: str = "astar", seed: int = 0, inflate: float = CREATE2_RADIUS,
         snap: float | None = None, rrt_iterations: int = 20000) -> list[Point] | None:
    """Smoothed waypoints from ``start`` to ``goal`` (world metres, both included), or None if unreachable
    (for RRT: not reached within ``rrt_iterations``)."""
    _check_planner(planner)
    pts = _points([start, goal], "path end points")
    if planner == "euclid":
        return [tuple(map(float, pts[0])), tuple(map(float, pts[1]))]
    grid = _grid(world_or_grid, inflate)
    snap = inflate + grid.resolution if snap is None else snap
    ix, iy = snap_cells(grid, pts, snap)
    if ix[0] < 0 or ix[1] < 0:
        return None
    if planner == "astar":
        if grid.segment_free(tuple(pts[0]), tuple(pts[1])):
            return [tuple(map(float, pts[0])), tuple(map(float, pts[1]))]
        _, cells = astar(grid, (int(ix[0]), int(iy[0])), (int(ix[1]), int(iy[1])))
        if cells is None:
            return None
        cx, cy = grid.cell_to_world(np.array([c[0] for c in cells]), np.array([c[1] for c in cells]))
        raw = list(zip(cx.tolist(), cy.tolist()))
    else:
        raw = rrt_multi(grid, grid.cell_to_world(ix[0], iy[0]), [grid.cell_to_world(ix[1], iy[1])],
                        max_iter=rrt_iterations, seed=seed)[0]
        if raw is None:
            return None
    return _with_ends(grid, smooth(grid, raw), pts[0], pts[1])
