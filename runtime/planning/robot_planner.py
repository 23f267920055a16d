"""One robot's planner on its map: bid costs for a batch of points, the route to drive, and the checks an
operator's task must pass.  Counts its fallbacks for the daemon's status.

``TravelEstimator`` prices tasks for the allocation agents (:class:`runtime.allocation.agent.Estimator`):
one planner search for a batch of tasks from the current pose estimate, reused until the robot has
moved 0.25 m or a different batch is asked for.  ``RobotPlanner.detour`` plans around obstacles the robot
sensed that its map does not hold (a stalled executor asks for one).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

from runtime import tasks as T
from runtime.config import WorldConfig, load_world
from runtime.log import get_logger

REPRICE_AFTER = 0.25       # m moved before a batch of bid costs is computed again
DETOUR_RESOLUTION = 0.1    # m: cells of a detour's grid when the robot has no map
DETOUR_WINDOW = 2.0        # m: how far beyond start and goal a map-less detour may go


@dataclass
class PlannerStats:
    plan_fallbacks: int = 0        # RRT found no path, the A* path was taken
    bid_fallbacks: int = 0         # bid costs the first RRT tree missed (priced by a second tree or A*)
    plan_failures: int = 0         # no path at all: headed straight for the goal
    detours: int = 0               # paths planned around sensed obstacles


class RobotPlanner:
    def __init__(self, world: WorldConfig | None, planner: str, inflate: float, rrt_iterations: int, seed: int,
                 robot_id: int | None = None):
        self.world = world
        self.planner = planner if world is not None else "euclid"
        self.inflate = float(inflate)
        self.rrt_iterations = int(rrt_iterations)
        self.seed = int(seed)
        self.stats = PlannerStats()
        self.log = get_logger("planning", robot_id)

    @classmethod
    def from_config(cls, cfg, radius: float) -> "RobotPlanner":
        """From a robot config: its map (relative to the config file), planner, and obstacle inflation (the
        base's radius unless ``planning.inflate`` says otherwise)."""
        p = cfg.planning
        world = None
        if p.map is not None:
            path = Path(p.map)
            if not path.is_absolute() and cfg.source:
                path = Path(cfg.source).parent / path
            world = load_world(path)
        inflate = p.inflate if p.inflate is not None else radius
        return cls(world, p.planner, inflate, p.rrt_iterations, cfg.robot.id, cfg.robot.id)

    def costs(self, start: Sequence[float], points: Sequence[tuple[float, float]]) -> list[float]:
        from runtime.planning.costs import bid_costs

        row, missed = bid_costs(self.world, start[:2], list(points), planner=self.planner, seed=self.seed,
                                inflate=self.inflate, rrt_iterations=self.rrt_iterations)
        self.stats.bid_fallbacks += missed
        return [float(c) for c in row]

    def route(self, pose: Sequence[float], goal: tuple[float, float]) -> list[tuple[float, float]]:
        """The path to drive to ``goal``: the planner's, A*'s when RRT misses, a straight line when the map
        has no path at all."""
        from runtime.planning.costs import plan_route

        if self.world is None:
            return [(pose[0], pose[1]), goal]
        route, used = plan_route(self.world, pose[:2], goal, planner=self.planner, seed=self.seed,
                                 inflate=self.inflate, rrt_iterations=self.rrt_iterations)
        if route is None:
            self.stats.plan_failures += 1
            self.log.warning("no path to (%.2f, %.2f) on the map: heading straight for it", *goal)
            return [(pose[0], pose[1]), goal]
        if used != self.planner:
            self.stats.plan_fallbacks += 1
            self.log.warning("%s found no path to (%.2f, %.2f) in two trees: following the %s path", self.planner,
                             *goal, used)
        return route

    def detour(self, pose: Sequence[float], goal: tuple[float, float], obstacles: Sequence[Sequence[float]],
               clearance: float | None = None, window: float = DETOUR_WINDOW) -> list[tuple[float, float]] | None:
        """A path to ``goal`` around sensed ``obstacles`` (world (x, y) points the map does not hold: another
        robot, a box), each kept ``clearance`` m off (default: the robot's inflation); planned by A* on the map's
        grid with the points added, or, without a map, on a grid of ``DETOUR_RESOLUTION`` m around start and goal
        (``window`` m beyond them).  None when the points leave no way (the caller keeps its path and waits)."""
        import numpy as np

        from runtime.planning.costs import grid_for, path
        from runtime.planning.grid import OccupancyGrid

        pts = np.asarray([o[:2] for o in obstacles], dtype=float).reshape(-1, 2)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        r = self.inflate if clearance is None else float(clearance)
        if self.world is not None:
            base = grid_for(self.world, self.inflate)
            occ, res, origin = np.array(base.occ), base.resolution, base.origin
        else:
            res = DETOUR_RESOLUTION
            lo = np.minimum(pose[:2], goal) - window
            hi = np.maximum(pose[:2], goal) + window
            n = np.ceil((hi - lo) / res).astype(int)
            occ, origin = np.zeros((n[1], n[0]), dtype=bool), (float(lo[0]), float(lo[1]))
        ny, nx = occ.shape
        cy, cx = np.mgrid[0:ny, 0:nx]
        wx, wy = origin[0] + (cx + 0.5) * res, origin[1] + (cy + 0.5) * res
        for ox, oy in pts:
            occ |= (wx - ox) ** 2 + (wy - oy) ** 2 <= r * r
        route = path(OccupancyGrid(occ, res, origin), pose[:2], goal, planner="astar", inflate=0.0,
                     snap=r + res)
        self.stats.detours += route is not None
        return route

    def refuse(self, pose: Sequence[float] | None, x: float, y: float) -> str | None:
        """Why a task at (x, y) cannot be taken (off the map, in an obstacle, unreachable from ``pose``), or
        None."""
        if not (math.isfinite(x) and math.isfinite(y)):
            return "its position is not a finite number"
        if self.world is None:
            return None
        from runtime.planning.costs import grid_for, snap_cells
        import numpy as np

        sx, sy = self.world.size
        if abs(x) > sx / 2 or abs(y) > sy / 2:
            return f"({x:.2f}, {y:.2f}) is off the map ({sx:g} x {sy:g} m centred on the origin)"
        grid = grid_for(self.world, self.inflate)
        ix, _ = snap_cells(grid, np.array([[x, y]]), 0.0)
        if ix[0] < 0:
            return f"({x:.2f}, {y:.2f}) is inside an obstacle (inflated by the robot radius {self.inflate:.2f} m)"
        if pose is not None:
            from runtime.planning.costs import cost_matrix
            if not math.isfinite(cost_matrix(self.world, [pose[:2]], [(x, y)], planner="astar",
                                             inflate=self.inflate)[0, 0]):
                return f"({x:.2f}, {y:.2f}) cannot be reached from ({pose[0]:.2f}, {pose[1]:.2f})"
        return None


class TravelEstimator:
    """Estimates for the allocation agent: the task kind's estimate over this robot's planned travel."""

    def __init__(self, planner: RobotPlanner, profile: T.Profile, pose: Callable[[], Sequence[float] | None]):
        self.planner = planner
        self.profile = profile
        self.pose = pose
        self._row: dict[tuple[float, float], float] = {}
        self._points: tuple = ()
        self._at: tuple[float, float] | None = None

    def estimates(self, tasks: Sequence[T.Task]) -> list[T.Estimate]:
        pose = self.pose()
        if pose is None:
            return [T.Estimate(math.inf, math.inf) for _ in tasks]
        points = tuple(t.position for t in tasks if t.position is not None)
        if (self._at is None or points != self._points
                or math.hypot(pose[0] - self._at[0], pose[1] - self._at[1]) > REPRICE_AFTER):
            self._row = dict(zip(points, self.planner.costs(pose, points)))
            self._points, self._at = points, (pose[0], pose[1])
        row = self._row

        def travel(x: float, y: float) -> float:
            return row.get((x, y), math.inf)

        return [T.estimate(t, self.profile, travel) for t in tasks]
