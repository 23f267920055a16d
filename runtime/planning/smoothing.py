"""Path smoothing on an occupancy grid: drop collinear points, then greedy line-of-sight shortcuts.

Works on any polyline of world (x, y) points whose consecutive segments are collision-free (A* cell paths,
RRT branches): every segment of the result is checked with ``OccupancyGrid.segment_free``, so the result is
collision-free too and never longer than the input.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from runtime.planning.grid import OccupancyGrid

Point = tuple[float, float]


def path_length(points: Sequence[Sequence[float]]) -> float:
    """Length of a polyline in metres (0 for fewer than two points)."""
    a = np.asarray(points, dtype=float).reshape(-1, 2)
    return float(np.hypot(*np.diff(a, axis=0).T).sum()) if len(a) > 1 else 0.0


def drop_collinear(points: Sequence[Sequence[float]], tol: float = 1e-9) -> list[Point]:
    """Remove interior points that lie on the straight line through their neighbours (and repeats)."""
    pts = [(float(p[0]), float(p[1])) for p in points]
    if len(pts) <= 2:
        return pts
    out = [pts[0]]
    for i in range(1, len(pts) - 1):
        ax, ay = out[-1]
        bx, by = pts[i]
        cx, cy = pts[i + 1]
        if (bx, by) == (ax, ay):
            continue
        cross = (bx - ax) * (cy - by) - (by - ay) * (cx - bx)
        dot = (bx - ax) * (cx - bx) + (by - ay) * (cy - by)
        if abs(cross) <= tol and dot >= 0:
            continue
        out.append((bx, by))
    if pts[-1] != out[-1] or len(out) == 1:
        out.append(pts[-1])
    return out


def shortcut(grid: OccupancyGrid, points: Sequence[Sequence[float]]) -> list[Point]:
    """Greedy shortcut smoothing: from each kept point, walk forward while the later points stay in line of
    sight and jump to the last one seen (linear in the number of points).

    The first and last points are kept.  If even the next point is not visible (an input segment that is
    itself blocked), it is kept as is, so the input is never made worse.
    """
    pts = drop_collinear(points)
    if len(pts) <= 2:
        return pts
    out = [pts[0]]
    i, n = 0, len(pts)
    while i < n - 1:
        nxt = i + 1
        while nxt + 1 < n and grid.segment_free(pts[i], pts[nxt + 1]):
            nxt += 1
        out.append(pts[nxt])
        i = nxt
    return out


def smooth(grid: OccupancyGrid, points: Sequence[Sequence[float]]) -> list[Point]:
    """Shortcut smoothing, applied until the length stops improving (at most a few passes)."""
    best = shortcut(grid, points)
    length = path_length(best)
    for _ in range(3):
        again = shortcut(grid, best)
        new = path_length(again)
        if not new < length - 1e-12:
            break
        best, length = again, new
    return best


def densify(points: Sequence[Sequence[float]], spacing: float) -> list[Point]:
    """Insert points so no segment is longer than ``spacing`` (e.g. before following with pure pursuit)."""
    pts = [(float(p[0]), float(p[1])) for p in points]
    if len(pts) < 2 or not spacing > 0:
        return pts
    out = [pts[0]]
    for (ax, ay), (bx, by) in zip(pts, pts[1:]):
        k = max(1, math.ceil(math.hypot(bx - ax, by - ay) / spacing))
        out.extend((ax + (bx - ax) * i / k, ay + (by - ay) * i / k) for i in range(1, k + 1))
    return out
