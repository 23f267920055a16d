"""Occupancy grids: world <-> cell conversion, rasterising world configs, random obstacle fields.

Cells are indexed ``occ[iy, ix]`` (row = y).  ``origin`` is the world (x, y) of the lower-left corner of
cell (0, 0); the centre of cell (ix, iy) is ``origin + (i + 0.5) * resolution``.  ``True`` = not navigable.
"""
from __future__ import annotations

import math
from typing import Iterable

import numpy as np
from scipy import ndimage

from runtime.config import Box, WorldConfig
from runtime.drivers.create_oi_protocol import GEOMETRY
from runtime.errors import InputError

# metres: the default inflation, an iRobot Create 2 (a robot's own base gives base.footprint.radius)
CREATE2_RADIUS = GEOMETRY["create2"].radius_mm / 1000.0


class OccupancyGrid:
    """A boolean occupancy grid with a metric frame."""

    def __init__(self, occ: np.ndarray, resolution: float, origin: tuple[float, float] = (0.0, 0.0)):
        occ = np.asarray(occ)
        if occ.ndim != 2 or occ.shape[0] < 1 or occ.shape[1] < 1:
            raise InputError(f"occupancy grid: expected a non-empty 2-D array, got shape {occ.shape}")
        if not (isinstance(resolution, (int, float)) and math.isfinite(resolution) and resolution > 0):
            raise InputError(f"occupancy grid resolution: expected a finite number > 0 (m), got {resolution!r}")
        ox, oy = (float(v) for v in origin)
        if not (math.isfinite(ox) and math.isfinite(oy)):
            raise InputError(f"occupancy grid origin: expected finite (x, y), got {origin!r}")
        self.occ = np.array(occ, dtype=bool, order="C")      # own copy, frozen: derived graphs are cached
        self.occ.setflags(write=False)
        self.resolution = float(resolution)
        self.origin = (ox, oy)
        self._cache: dict = {}      # derived data (graphs) keyed by the module that builds them

    # ------------------------------------------------------------------ frame
    @property
    def shape(self) -> tuple[int, int]:
        """(ny, nx)."""
        return self.occ.shape

    @property
    def size_m(self) -> tuple[float, float]:
        return self.occ.shape[1] * self.resolution, self.occ.shape[0] * self.resolution

    @property
    def occupied_fraction(self) -> float:
        return float(self.occ.mean())

    def world_to_cell(self, x, y):
        """Cell indices (ix, iy) containing world point(s) (x, y); may lie outside the grid."""
        ix = np.floor((np.asarray(x, dtype=float) - self.origin[0]) / self.resolution).astype(np.int64)
        iy = np.floor((np.asarray(y, dtype=float) - self.origin[1]) / self.resolution).astype(np.int64)
        if ix.ndim == 0:
            return int(ix), int(iy)
        return ix, iy

    def cell_to_world(self, ix, iy):
        """World (x, y) of the centre of cell(s) (ix, iy)."""
        x = self.origin[0] + (np.asarray(ix, dtype=float) + 0.5) * self.resolution
        y = self.origin[1] + (np.asarray(iy, dtype=float) + 0.5) * self.resolution
        if x.ndim == 0:
            return float(x), float(y)
        return x, y

    def in_bounds(self, ix, iy):
        ny, nx = self.occ.shape
        return (np.asarray(ix) >= 0) & (np.asarray(ix) < nx) & (np.asarray(iy) >= 0) & (np.asarray(iy) < ny)

    def is_free_cell(self, ix: int, iy: int) -> bool:
        return bool(self.in_bounds(ix, iy)) and not self.occ[iy, ix]

    def is_free(self, x: float, y: float) -> bool:
        """True if world point (x, y) is inside the grid and its cell is navigable."""
        return self.is_free_cell(*self.world_to_cell(x, y))

    # ------------------------------------------------------------------ geometry
    def segments_cells(self, p, q) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cells touched by each segment p[k]-q[k] (arrays (K, 2) in world metres): (segment, ix, iy).

        Supercover: the cells holding the end points (and just inside them), the two cells on either side
        of every grid-line crossing, and at a grid vertex all four cells around it, so a segment cannot slip between two
        cells that share only a corner.  Cells may repeat.  Vectorised over segments.
        """
        p = np.asarray(p, dtype=float).reshape(-1, 2)
        q = np.asarray(q, dtype=float).reshape(-1, 2)
        res, (ox, oy) = self.resolution, self.origin
        a = (p - (ox, oy)) / res
        b = (q - (ox, oy)) / res
        d = b - a
        k_all = np.arange(len(a))
        # End cells, and the cells just inside each end (an end on a grid line or vertex is counted in the
        # cell above/right of it, which the segment may not enter).
        out_k = [k_all, k_all, k_all, k_all]
        out_c = [np.floor(v).astype(np.int64) for v in (a, b, a + 1e-9 * d, b - 1e-9 * d)]
        for axis in (0, 1):
            other = 1 - axis
            lo = np.floor(np.minimum(a[:, axis], b[:, axis])) + 1
            count = np.maximum(np.ceil(np.maximum(a[:, axis], b[:, axis])) - lo, 0).astype(np.int64)
            count[d[:, axis] == 0] = 0
            k = np.repeat(k_all, count)
            first = np.repeat(np.cumsum(count) - count, count)
            line = np.repeat(lo, count) + (np.arange(len(k)) - first)
            t = (line - a[k, axis]) / d[k, axis]
            along = a[k, other] + t * d[k, other]           # where the segment crosses this line
            near = np.rint(along)
            at_vertex = np.abs(along - near) < 1e-9
            cross = np.floor(along).astype(np.int64)
            line = line.astype(np.int64)
            for side in (line - 1, line):
                c = np.empty((len(k), 2), np.int64)
                c[:, axis], c[:, other] = side, cross
                out_k.append(k)
                out_c.append(c)
                if at_vertex.any():                       # through a vertex: the cells below/left of it too
                    v = c[at_vertex].copy()
                    v[:, other] = near[at_vertex].astype(np.int64) - 1
                    out_k.append(k[at_vertex])
                    out_c.append(v)
        c = np.concatenate(out_c)
        return np.concatenate(out_k), c[:, 0], c[:, 1]

    def segment_cells(self, p: tuple[float, float], q: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
        """All cells (ix, iy) the segment p-q touches (see ``segments_cells``)."""
        _, ix, iy = self.segments_cells([p], [q])
        return ix, iy

    def segments_free(self, p, q) -> np.ndarray:
        """Per segment p[k]-q[k]: True if every cell it touches is inside the grid and navigable."""
        k, ix, iy = self.segments_cells(p, q)
        inside = self.in_bounds(ix, iy)
        bad = ~inside
        bad[inside] = self.occ[iy[inside], ix[inside]]
        n = len(np.asarray(p, dtype=float).reshape(-1, 2))
        return np.bincount(k[bad], minlength=n) == 0

    def segment_free(self, p: tuple[float, float], q: tuple[float, float]) -> bool:
        """True if every cell the segment p-q touches is inside the grid and navigable.

        Same cells as ``segments_cells``; short segments (RRT steps) are walked in plain Python, which
        is several times faster than the vectorised version for a handful of cells.
        """
        res, (ox, oy) = self.resolution, self.origin
        a = ((p[0] - ox) / res, (p[1] - oy) / res)
        b = ((q[0] - ox) / res, (q[1] - oy) / res)
        d = (b[0] - a[0], b[1] - a[1])
        if abs(d[0]) + abs(d[1]) > 48:
            return bool(self.segments_free([p], [q])[0])
        occ = self.occ
        ny, nx = occ.shape

        def blocked(ix: int, iy: int) -> bool:
            return not (0 <= ix < nx and 0 <= iy < ny) or bool(occ[iy, ix])

        e = 1e-9
        for x, y in (a, b, (a[0] + e * d[0], a[1] + e * d[1]), (b[0] - e * d[0], b[1] - e * d[1])):
            if blocked(math.floor(x), math.floor(y)):
                return False
        for axis in (0, 1):
            if d[axis] == 0:
                continue
            other = 1 - axis
            for line in range(math.floor(min(a[axis], b[axis])) + 1, math.ceil(max(a[axis], b[axis]))):
                along = a[other] + (line - a[axis]) / d[axis] * d[other]
                rows = [math.floor(along)]
                if abs(along - round(along)) < 1e-9:
                    rows.append(round(along) - 1)
                for side in (line - 1, line):
                    for r in rows:
                        if blocked(side, r) if axis == 0 else blocked(r, side):
                            return False
        return True

    # ------------------------------------------------------------------ derived grids
    def inflate(self, radius: float) -> "OccupancyGrid":
        """Grid with every cell within ``radius`` of an occupied cell's edge marked occupied.

        Uses the Euclidean distance transform between cell centres; a cell is blocked when its centre is
        within radius + half a cell of an occupied cell's centre.
        """
        if not (math.isfinite(radius) and radius >= 0):
            raise InputError(f"inflation radius: expected a finite number >= 0 (m), got {radius!r}")
        if radius == 0 or not self.occ.any():
            return OccupancyGrid(self.occ.copy(), self.resolution, self.origin)
        dist = ndimage.distance_transform_edt(~self.occ, sampling=self.resolution)
        return OccupancyGrid(dist <= radius + 0.5 * self.resolution + 1e-9, self.resolution, self.origin)

    def free_cells(self, n: int, seed: int | np.random.Generator = 0, component: str = "largest",
                   clearance: int = 0) -> np.ndarray:
        """``n`` distinct free cell centres (world xy, shape (n, 2)) drawn at random.

        ``component="largest"`` draws only from the largest 4-connected free region, so every pair is
        mutually reachable (8-connected moves without corner cutting connect exactly the 4-connected
        regions); ``"any"`` draws from every free cell.  ``clearance`` keeps that many cells off the border.
        """
        rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        free = ~self.occ
        if clearance:
            free = free.copy()
            free[:clearance, :] = free[-clearance:, :] = False
            free[:, :clearance] = free[:, -clearance:] = False
        if component == "largest":
            labels, count = ndimage.label(free)
            if count:
                sizes = np.bincount(labels.ravel())
                sizes[0] = 0
                free = labels == int(np.argmax(sizes))
        elif component != "any":
            raise InputError(f"free_cells component: expected 'largest' or 'any', got {component!r}")
        iy, ix = np.nonzero(free)
        if len(ix) < n:
            raise InputError(f"free_cells: asked for {n} distinct free cells, the grid has {len(ix)}")
        pick = rng.choice(len(ix), size=n, replace=False)
        x, y = self.cell_to_world(ix[pick], iy[pick])
        return np.column_stack((np.atleast_1d(x), np.atleast_1d(y)))

    # ------------------------------------------------------------------ constructors
    @classmethod
    def empty(cls, size_m: float | tuple[float, float], resolution: float) -> "OccupancyGrid":
        """An all-free grid of ``size_m`` metres centred on the origin."""
        sx, sy = _size_pair(size_m)
        nx, ny = _cells(sx, resolution), _cells(sy, resolution)
        return cls(np.zeros((ny, nx), dtype=bool), resolution, (-nx * resolution / 2, -ny * resolution / 2))

    @classmethod
    def from_world(cls, cfg: WorldConfig, inflate: float = CREATE2_RADIUS,
                   resolution: float | None = None) -> "OccupancyGrid":
        """Rasterise a world's boxes (yawed too) and, if ``cfg.walls``, its arena walls; inflate by ``inflate``."""
        res = float(resolution if resolution is not None else cfg.resolution)
        grid = cls.empty(cfg.size, res)
        occ = rasterise_boxes(grid, cfg.obstacles)
        if not cfg.walls:
            return OccupancyGrid(occ, res, grid.origin).inflate(inflate)
        # Walls: a ring of occupied cells just outside the arena, inflated with the rest, then cropped.
        padded = np.pad(occ, 1, constant_values=True)
        inflated = OccupancyGrid(padded, res, (grid.origin[0] - res, grid.origin[1] - res)).inflate(inflate)
        return cls(inflated.occ[1:-1, 1:-1], res, grid.origin)


def _size_pair(size_m) -> tuple[float, float]:
    sx, sy = (size_m, size_m) if np.isscalar(size_m) else size_m
    if not (math.isfinite(sx) and math.isfinite(sy) and sx > 0 and sy > 0):
        raise InputError(f"grid size: expected positive finite metres, got {size_m!r}")
    return float(sx), float(sy)


def _cells(length: float, resolution: float) -> int:
    if not (math.isfinite(resolution) and resolution > 0):
        raise InputError(f"grid resolution: expected a finite number > 0 (m), got {resolution!r}")
    n = int(math.ceil(length / resolution - 1e-9))
    if n > 20000:
        raise InputError(f"grid: {length} m at {resolution} m per cell is {n} cells a side, expected <= 20000")
    return max(n, 1)


def rasterise_boxes(grid: OccupancyGrid, boxes: Iterable[Box]) -> np.ndarray:
    """A copy of ``grid.occ`` with every cell whose centre lies in a (yawed) box set; tiny boxes mark their cell."""
    occ = grid.occ.copy()
    ny, nx = occ.shape
    res, (ox, oy) = grid.resolution, grid.origin
    for box in boxes:
        cx, cy = box.center
        hx, hy = box.size[0] / 2, box.size[1] / 2
        c, s = math.cos(box.yaw), math.sin(box.yaw)
        ex, ey = abs(c) * hx + abs(s) * hy, abs(s) * hx + abs(c) * hy     # axis-aligned half extents
        ix0 = max(int(math.floor((cx - ex - ox) / res)), 0)
        ix1 = min(int(math.ceil((cx + ex - ox) / res)), nx)
        iy0 = max(int(math.floor((cy - ey - oy) / res)), 0)
        iy1 = min(int(math.ceil((cy + ey - oy) / res)), ny)
        if ix0 < ix1 and iy0 < iy1:
            xs = ox + (np.arange(ix0, ix1) + 0.5) * res - cx
            ys = oy + (np.arange(iy0, iy1) + 0.5) * res - cy
            X, Y = np.meshgrid(xs, ys)
            lx, ly = c * X + s * Y, -s * X + c * Y
            occ[iy0:iy1, ix0:ix1] |= (np.abs(lx) <= hx + 1e-9) & (np.abs(ly) <= hy + 1e-9)
        ix, iy = grid.world_to_cell(cx, cy)
        if 0 <= ix < nx and 0 <= iy < ny:
            occ[iy, ix] = True
    return occ


def random_obstacle_boxes(size_m: float | tuple[float, float], resolution: float, fraction: float,
                          seed: int = 0, min_side: float | None = None,
                          max_side: float | None = None) -> tuple[OccupancyGrid, tuple[Box, ...]]:
    """Random axis-aligned blocks until ``fraction`` of the cells are non-navigable; returns (grid, boxes).

    Block sides are drawn uniformly in [min_side, max_side] (default 2 % to 8 % of the shorter arena side,
    1.5 m to 6 m on paper 002's 75 x 75 m field).  The grid is not inflated.
    """
    if not (isinstance(fraction, (int, float)) and 0 <= fraction < 1):
        raise InputError(f"obstacle fraction: expected a number in [0, 1), got {fraction!r}")
    grid = OccupancyGrid.empty(size_m, resolution)
    sx, sy = grid.size_m
    lo = min_side if min_side is not None else 0.02 * min(sx, sy)
    hi = max_side if max_side is not None else 0.08 * min(sx, sy)
    lo, hi = max(lo, resolution), max(hi, resolution)
    rng = np.random.default_rng(seed)
    occ = grid.occ.copy()
    boxes: list[Box] = []
    target = int(math.ceil(fraction * occ.size))
    count = 0
    while count < target:
        w, h = rng.uniform(lo, hi, size=2)
        cx = rng.uniform(grid.origin[0], grid.origin[0] + sx)
        cy = rng.uniform(grid.origin[1], grid.origin[1] + sy)
        box = Box(center=(float(cx), float(cy)), size=(float(w), float(h)))
        occ = rasterise_boxes(OccupancyGrid(occ, resolution, grid.origin), [box])
        new = int(occ.sum())
        if new > count:
            boxes.append(box)
            count = new
    return OccupancyGrid(occ, resolution, grid.origin), tuple(boxes)


def random_obstacle_field(size_m: float | tuple[float, float], resolution: float, fraction: float,
                          seed: int = 0) -> OccupancyGrid:
    """A grid of ``size_m`` metres (centred on the origin) with ``fraction`` non-navigable terrain in blocks.

    Paper 002 (Section IV-B) uses 5 %, 20 % and 40 % on 75 x 75 m.  Not inflated: call ``inflate``.
    """
    return random_obstacle_boxes(size_m, resolution, fraction, seed)[0]


def random_obstacle_world(size_m: float | tuple[float, float], resolution: float, fraction: float,
                          seed: int = 0, walls: bool = True) -> WorldConfig:
    """The same random field as a WorldConfig (boxes), e.g. for the pybullet SITL."""
    grid, boxes = random_obstacle_boxes(size_m, resolution, fraction, seed)
    return WorldConfig(size=grid.size_m, obstacles=boxes, walls=walls, resolution=resolution)
