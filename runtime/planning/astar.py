"""Shortest paths on an occupancy grid: A* for one path, a multi-source Dijkstra for whole cost matrices.

The grid graph: free cells are nodes; 8-connected by default, orthogonal moves cost ``resolution`` metres
and diagonal moves ``sqrt(2) * resolution``; a diagonal move needs both orthogonal cells it passes free
(no corner cutting).  With ``connectivity=4`` only orthogonal moves.  A* and the cost table (a vectorised
bucketed Dijkstra, or scipy's Dijkstra on ``grid_graph``) search this same graph, so their lengths agree.
"""
from __future__ import annotations

import heapq
import math
from typing import Sequence

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from runtime.errors import InputError
from runtime.planning.grid import OccupancyGrid

SQRT2 = math.sqrt(2.0)
Cell = tuple[int, int]


def _check_connectivity(connectivity: int) -> None:
    if connectivity not in (4, 8):
        raise InputError(f"grid connectivity: expected 4 or 8, got {connectivity!r}")


def grid_graph(grid: OccupancyGrid, connectivity: int = 8) -> tuple[csr_matrix, np.ndarray]:
    """(graph, node_of_cell): the grid graph over free cells as a sparse matrix of edge lengths in metres,
    and the flat-cell -> node index map (-1 for occupied cells).  Cached on the grid."""
    _check_connectivity(connectivity)
    key = ("graph", connectivity)
    if key in grid._cache:
        return grid._cache[key]
    free = ~grid.occ
    ny, nx = free.shape
    node = np.full(nx * ny, -1, dtype=np.int32)
    node[free.ravel()] = np.arange(int(free.sum()), dtype=np.int32)
    idx = node.reshape(ny, nx)
    offsets = [(0, 1), (1, 0), (0, -1), (-1, 0)]
    if connectivity == 8:
        offsets += [(1, 1), (1, -1), (-1, 1), (-1, -1)]
    src, dst, wts = [], [], []
    for dy, dx in offsets:
        ys, yd = slice(max(0, -dy), ny - max(0, dy)), slice(max(0, dy), ny - max(0, -dy))
        xs, xd = slice(max(0, -dx), nx - max(0, dx)), slice(max(0, dx), nx - max(0, -dx))
        ok = free[ys, xs] & free[yd, xd]
        if dx and dy:
            ok &= free[ys, xd] & free[yd, xs]     # both cells beside the diagonal
        src.append(idx[ys, xs][ok])
        dst.append(idx[yd, xd][ok])
        wts.append(np.full(int(ok.sum()), grid.resolution * (SQRT2 if dx and dy else 1.0)))
    n = int(free.sum())
    graph = csr_matrix((np.concatenate(wts), (np.concatenate(src), np.concatenate(dst))), shape=(n, n))
    grid._cache[key] = (graph, node)
    return graph, node


def _flat(grid: OccupancyGrid, cells: Sequence[Cell], what: str) -> np.ndarray:
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, 2)
    if not np.all(grid.in_bounds(cells[:, 0], cells[:, 1])):
        bad = cells[~grid.in_bounds(cells[:, 0], cells[:, 1])][0]
        raise InputError(f"{what} cell {tuple(int(v) for v in bad)}: expected inside the grid "
                         f"(0..{grid.shape[1] - 1}, 0..{grid.shape[0] - 1})")
    return cells[:, 1] * grid.shape[1] + cells[:, 0]


def _move_bits(grid: OccupancyGrid, connectivity: int) -> tuple[np.ndarray, list[int], list[float], int]:
    """Per cell of the grid padded by one occupied ring: a bit per allowed move (cached on the grid)."""
    key = ("bits", connectivity)
    if key not in grid._cache:
        ny, nx = grid.shape
        width = nx + 2
        f = np.pad(~grid.occ, 1, constant_values=False).ravel()
        moves = [(1, 0), (-1, 0), (0, 1), (0, -1)]
        if connectivity == 8:
            moves += [(1, 1), (1, -1), (-1, 1), (-1, -1)]
        bits = np.zeros(f.size, np.uint8)
        offsets, weights = [], []
        for k, (dx, dy) in enumerate(moves):
            o = dx + dy * width
            ok = f & np.roll(f, -o)           # the padding ring keeps np.roll from wrapping into free cells
            if dx and dy:
                ok &= np.roll(f, -dx) & np.roll(f, -dy * width)
            bits |= ok.astype(np.uint8) << k
            offsets.append(o)
            weights.append(grid.resolution * (SQRT2 if dx and dy else 1.0))
        grid._cache[key] = (bits, offsets, weights, width)
    return grid._cache[key]


def wavefront(grid: OccupancyGrid, sources: np.ndarray, targets: np.ndarray, connectivity: int = 8,
              max_elements: int = 16_000_000) -> np.ndarray:
    """Exact multi-source shortest-path lengths from flat free cells ``sources`` to flat cells ``targets``.

    Vectorised Dijkstra (Dinitz's bucketed variant): every move costs at least one cell length, so all
    frontier cells within one cell length of the frontier minimum are final and are expanded together,
    for all sources at once.  Sources are processed in chunks of at most ``max_elements`` states.
    """
    bits, offsets, weights, width = _move_bits(grid, connectivity)
    ny, nx = grid.shape
    P = bits.size
    out = np.full((len(sources), len(targets)), np.inf)
    t_pad = (targets // nx + 1) * width + targets % nx + 1
    step = grid.resolution * (1 - 1e-9)
    chunk = max(1, max_elements // P)
    for c0 in range(0, len(sources), chunk):
        src = sources[c0:c0 + chunk]
        K = len(src)
        bitsK = np.tile(bits, K)
        start = np.arange(K, dtype=np.int64) * P + (src // nx + 1) * width + src % nx + 1
        dist = np.full(K * P, np.inf)
        dist[start] = 0.0
        in_frontier = np.zeros(K * P, dtype=bool)
        in_frontier[start] = True
        frontier = start
        while len(frontier):
            d_f = dist[frontier]
            settle = d_f < d_f.min() + step
            batch, d_b = frontier[settle], d_f[settle]
            in_frontier[batch] = False
            moves = bitsK[batch]
            grown = [frontier[~settle]]
            for k, (o, w) in enumerate(zip(offsets, weights)):
                can = (moves & (1 << k)).astype(bool)
                nb = batch[can] + o
                nd = d_b[can] + w
                better = nd < dist[nb]
                nb = nb[better]
                dist[nb] = nd[better]          # one move direction: no repeated cells, plain assignment
                nb = nb[~in_frontier[nb]]
                in_frontier[nb] = True
                grown.append(nb)
            frontier = np.concatenate(grown)
        out[c0:c0 + K] = dist.reshape(K, P)[:, t_pad]
    return out


def cost_table(grid: OccupancyGrid, sources: Sequence[Cell], targets: Sequence[Cell],
               connectivity: int = 8, method: str = "wavefront") -> np.ndarray:
    """Shortest-path lengths (metres) from every source cell to every target cell; inf if unreachable
    (including a source or target on an occupied cell).

    One search per distinct source or per distinct target, whichever side is smaller (the graph is
    undirected).  ``method="wavefront"`` (default, vectorised, all searches at once) or ``"scipy"``
    (scipy.sparse.csgraph.dijkstra on ``grid_graph``); both give the same lengths.
    """
    _check_connectivity(connectivity)
    if method not in ("wavefront", "scipy"):
        raise InputError(f"cost_table method: expected 'wavefront' or 'scipy', got {method!r}")
    s = _flat(grid, sources, "source")
    t = _flat(grid, targets, "target")
    occ = grid.occ.ravel()
    table = np.full((len(s), len(t)), np.inf)
    ok_s, ok_t = ~occ[s], ~occ[t]
    if not ok_s.any() or not ok_t.any():
        return table
    flip = ok_s.sum() > ok_t.sum()
    a, b = (t[ok_t], s[ok_s]) if flip else (s[ok_s], t[ok_t])
    starts = np.unique(a)
    if method == "wavefront":
        dist = wavefront(grid, starts, b, connectivity)
    else:
        graph, node = grid_graph(grid, connectivity)
        dist = dijkstra(graph, directed=True, indices=node[starts])[:, node[b]]
    sub = dist[np.searchsorted(starts, a)]
    table[np.ix_(ok_s, ok_t)] = sub.T if flip else sub
    return table


def astar(grid: OccupancyGrid, start: Cell, goal: Cell, connectivity: int = 8) -> tuple[float, list[Cell] | None]:
    """A* from cell ``start`` to cell ``goal`` (each (ix, iy)): (length in metres, cells) or (inf, None).

    Octile heuristic (Manhattan with 4-connectivity), which is consistent, so the first time the goal is
    popped its cost is optimal.
    """
    _check_connectivity(connectivity)
    ny, nx = grid.shape
    s = int(_flat(grid, [start], "start")[0])
    g = int(_flat(grid, [goal], "goal")[0])
    occ = grid.occ.ravel()
    if occ[s] or occ[g]:
        return math.inf, None
    if s == g:
        return 0.0, [(s % nx, s // nx)]
    res = grid.resolution
    diag = res * SQRT2
    gx, gy = g % nx, g // nx
    blocked = occ.tolist()
    if connectivity == 8:
        def h(x: int, y: int) -> float:
            dx, dy = abs(x - gx), abs(y - gy)
            return res * (dx + dy) + (diag - 2 * res) * (dx if dx < dy else dy)
    else:
        def h(x: int, y: int) -> float:
            return res * (abs(x - gx) + abs(y - gy))
    INF = math.inf
    cost = {s: 0.0}
    parent = {s: -1}
    closed = set()
    heap = [(h(s % nx, s // nx), 0.0, s)]
    push, pop = heapq.heappush, heapq.heappop
    while heap:
        f, c, i = pop(heap)
        if i in closed:
            continue
        if i == g:
            break
        closed.add(i)
        x, y = i % nx, i // nx
        left, right, down, up = x > 0, x < nx - 1, y > 0, y < ny - 1
        fl = left and not blocked[i - 1]
        fr = right and not blocked[i + 1]
        fd = down and not blocked[i - nx]
        fu = up and not blocked[i + nx]
        moves = []
        if fl: moves.append((i - 1, x - 1, y, res))
        if fr: moves.append((i + 1, x + 1, y, res))
        if fd: moves.append((i - nx, x, y - 1, res))
        if fu: moves.append((i + nx, x, y + 1, res))
        if connectivity == 8:
            if fl and fd and not blocked[i - nx - 1]: moves.append((i - nx - 1, x - 1, y - 1, diag))
            if fr and fd and not blocked[i - nx + 1]: moves.append((i - nx + 1, x + 1, y - 1, diag))
            if fl and fu and not blocked[i + nx - 1]: moves.append((i + nx - 1, x - 1, y + 1, diag))
            if fr and fu and not blocked[i + nx + 1]: moves.append((i + nx + 1, x + 1, y + 1, diag))
        for j, jx, jy, w in moves:
            if j in closed:
                continue
            nc = c + w
            if nc < cost.get(j, INF):
                cost[j] = nc
                parent[j] = i
                push(heap, (nc + h(jx, jy), nc, j))
    else:
        return math.inf, None
    cells = []
    i = g
    while i != -1:
        cells.append((i % nx, i // nx))
        i = parent[i]
    cells.reverse()
    return cost[g], cells


def path_length(grid: OccupancyGrid, cells: Sequence[Cell]) -> float:
    """Sum of the step lengths (metres) of a cell path."""
    a = np.asarray(cells, dtype=float).reshape(-1, 2)
    return float(np.hypot(*np.diff(a, axis=0).T).sum() * grid.resolution) if len(a) > 1 else 0.0
