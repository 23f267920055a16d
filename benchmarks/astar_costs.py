"""Bid-cost matrix speed: runtime.planning vs pyastar2d (C++ A*) on the same grid, same pairs, same run.

20 robots x 20 tasks on a 300 x 300 grid with ~25 % obstacles (paper-002-style random blocks).
Ours: ``cost_matrix(grid, robots, tasks, "astar")`` (a vectorised bucketed Dijkstra from all robots at
once over the 8-connected grid graph, plus the straight-line check); scipy's Dijkstra on the same graph is
timed too.  Peer: ``pyastar2d.astar_path`` for each of the 400 pairs
(8-connected, as it ships: diagonal steps cost 1, corners may be cut).

Agreement: pyastar2d minimises a different metric in 8-connected mode, so lengths are compared exactly in
4-connected mode (both are shortest paths on the same 4-connected graph), and in 8-connected mode our A*
is checked against our Dijkstra table on sampled pairs.

    .venv/bin/python benchmarks/astar_costs.py [--repeat 5] [--seed 1] [--fraction 0.25] [--cells 300]
"""
from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import pyastar2d

from runtime.planning.astar import astar, cost_table
from runtime.planning.costs import cost_matrix
from runtime.planning.grid import OccupancyGrid, random_obstacle_field


def peer_matrix(weights: np.ndarray, rcells, tcells, diagonal: bool) -> tuple[np.ndarray, list]:
    """pyastar2d for every pair: (steps per pair, paths); cells are (ix, iy), pyastar2d wants (row, col)."""
    steps = np.full((len(rcells), len(tcells)), np.inf)
    paths = []
    for i, (rx, ry) in enumerate(rcells):
        for j, (tx, ty) in enumerate(tcells):
            p = pyastar2d.astar_path(weights, (ry, rx), (ty, tx), allow_diagonal=diagonal)
            paths.append(p)
            if p is not None:
                steps[i, j] = len(p) - 1
    return steps, paths


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=int, default=300)
    ap.add_argument("--resolution", type=float, default=0.1)
    ap.add_argument("--fraction", type=float, default=0.25)
    ap.add_argument("--robots", type=int, default=20)
    ap.add_argument("--tasks", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--check-astar", type=int, default=20, help="pairs on which to compare our A* with Dijkstra")
    a = ap.parse_args(argv)

    grid = random_obstacle_field(a.cells * a.resolution, a.resolution, a.fraction, seed=a.seed)
    pts = grid.free_cells(a.robots + a.tasks, seed=a.seed + 1)
    robots, tasks = pts[: a.robots], pts[a.robots:]
    rc = [grid.world_to_cell(x, y) for x, y in robots]
    tc = [grid.world_to_cell(x, y) for x, y in tasks]
    weights = np.where(grid.occ, np.inf, 1.0).astype(np.float32)
    print(f"grid {grid.shape[1]} x {grid.shape[0]} cells at {a.resolution} m, "
          f"{100 * grid.occupied_fraction:.1f} % occupied; {a.robots} robots x {a.tasks} tasks; "
          f"median of {a.repeat} runs")

    ours_cold, ours_warm, scipy_d, peer = [], [], [], []
    for _ in range(a.repeat):
        fresh = OccupancyGrid(grid.occ, grid.resolution, grid.origin)     # nothing cached: cold
        t0 = time.perf_counter()
        mine = cost_matrix(fresh, robots, tasks, planner="astar")
        t1 = time.perf_counter()
        cost_matrix(fresh, robots, tasks, planner="astar")
        t2 = time.perf_counter()
        peer_matrix(weights, rc, tc, diagonal=True)
        t3 = time.perf_counter()
        cost_table(OccupancyGrid(grid.occ, grid.resolution, grid.origin), rc, tc, method="scipy")
        t4 = time.perf_counter()
        ours_cold.append(t1 - t0)
        ours_warm.append(t2 - t1)
        peer.append(t3 - t2)
        scipy_d.append(t4 - t3)
    oc, ow, pp, sd = (statistics.median(v) for v in (ours_cold, ours_warm, peer, scipy_d))
    print(f"8-connected  ours cost_matrix, cold grid:        {oc * 1e3:8.1f} ms")
    print(f"8-connected  ours cost_matrix, masks cached:     {ow * 1e3:8.1f} ms")
    print(f"8-connected  scipy csgraph Dijkstra table, cold: {sd * 1e3:8.1f} ms")
    print(f"8-connected  pyastar2d, {a.robots * a.tasks} paths:            {pp * 1e3:8.1f} ms")
    print(f"ratio ours/pyastar2d: {oc / pp:.2f} cold, {ow / pp:.2f} cached; scipy table/pyastar2d: {sd / pp:.2f}"
          f"  [<= 1: faster than pyastar2d]")

    # 4-connected: both compute shortest paths on the same graph, so the lengths must be identical.
    t0 = time.perf_counter()
    ours4 = cost_table(grid, rc, tc, connectivity=4)
    t1 = time.perf_counter()
    steps4, _ = peer_matrix(weights, rc, tc, diagonal=False)
    t2 = time.perf_counter()
    agree4 = np.array_equal(np.isinf(ours4), np.isinf(steps4)) and \
        np.allclose(ours4[np.isfinite(ours4)], steps4[np.isfinite(steps4)] * a.resolution, rtol=0, atol=1e-9)
    print(f"4-connected  ours {1e3 * (t1 - t0):.1f} ms, pyastar2d {1e3 * (t2 - t1):.1f} ms, "
          f"ratio {(t1 - t0) / (t2 - t1):.2f}; lengths agree on all {ours4.size} pairs: {agree4}")

    # 8-connected: our A* == our Dijkstra table on sampled pairs; pyastar2d's paths measured in metres.
    table8 = cost_table(grid, rc, tc)
    rng = np.random.default_rng(a.seed)
    pairs = [(int(i), int(j)) for i, j in zip(rng.integers(a.robots, size=a.check_astar),
                                              rng.integers(a.tasks, size=a.check_astar))]
    agree8 = all(abs(astar(grid, rc[i], tc[j])[0] - table8[i, j]) < 1e-9 for i, j in pairs)
    print(f"8-connected  our A* == our Dijkstra table on {len(pairs)} sampled pairs: {agree8}")
    _, ppaths = peer_matrix(weights, rc, tc, diagonal=True)
    metres = np.array([np.hypot(*np.diff(p, axis=0).T).sum() * a.resolution for p in ppaths if p is not None])
    finite = table8[np.isfinite(table8)].ravel()
    print(f"8-connected  pyastar2d paths in metres / our shortest: mean {np.mean(metres / finite):.4f}, "
          f"min {np.min(metres / finite):.4f} (it minimises steps and may cut corners)")
    print(f"cost_matrix vs grid table: {np.mean(mine <= table8 + 1e-9) * 100:.0f} % of pairs <= grid length "
          f"(straight-line pairs priced at their Euclidean length)")


if __name__ == "__main__":
    main()
