"""``surveillance`` (paper 003 Section 3): visit every waypoint of a grid over a region at least once.

A task kind module (``KIND``, ``Spec``, ``COMMANDS``, ``EXECUTOR``, ``estimate``, ``from_item``, ``to_item``),
allocated by CoMutaR (:mod:`runtime.allocation.comutar`).  The paper's "set of waypoints
around a 2 x 2 m region" conflicts with its Fig. 4 (robots over about +-8 m); the digest's reading is a
grid of waypoints 2 m apart over about 16 x 16 m (9 x 9), which is the default here.

Mission item: MAV_CMD_SPATIAL_USER_1 (31005) at the region's centre; param1 = width (m), param2 = height (m),
param3 = spacing (m), param4 = the most robots that take part (0: every robot that can).

Several robots serve one surveillance task: the auction awards every feasible single-robot coalition (up to
``robots``), the waypoint set is shared, each visit is broadcast, and a robot heads for the nearest waypoint
no other robot has claimed (:class:`Board`; first claim wins).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from runtime.config.build import rng
from runtime.tasks.model import Estimate, Profile, Travel

KIND = "surveillance"
EXECUTOR = "runtime.execution.surveillance:SurveillanceExecutor"
MAV_CMD_SPATIAL_USER_1 = 31005
COMMANDS = (MAV_CMD_SPATIAL_USER_1,)
VISITED = "visited"          # Progress event of a surveillance executor: data["waypoint"]
MAX_WAYPOINTS = 200          # CmSurvey carries visited waypoints as a uint8 array (index + 1)
MAX_SIDE = 1000.0


@dataclass(frozen=True)
class Surveillance:
    x: float                                                             # m, centre of the region, fleet frame
    y: float
    width: float = field(default=16.0, metadata=rng(0.0, MAX_SIDE))     # m along x
    height: float = field(default=16.0, metadata=rng(0.0, MAX_SIDE))    # m along y
    spacing: float = field(default=2.0, metadata=rng(0.01, MAX_SIDE, lo_open=True))   # m between waypoints
    robots: int = field(default=0, metadata=rng(0, 250))                 # most robots taking part; 0: all

    def waypoints(self) -> np.ndarray:
        """The grid (N, 2), row by row from the bottom-left corner: floor(side / spacing) + 1 per side."""
        nx = int(math.floor(self.width / self.spacing + 1e-9)) + 1
        ny = int(math.floor(self.height / self.spacing + 1e-9)) + 1
        xs = self.x + (np.arange(nx) - (nx - 1) / 2) * self.spacing
        ys = self.y + (np.arange(ny) - (ny - 1) / 2) * self.spacing
        gx, gy = np.meshgrid(xs, ys)
        return np.stack([gx.ravel(), gy.ravel()], axis=1)


Spec = Surveillance


def count(spec: Surveillance) -> int:
    nx = int(math.floor(spec.width / spec.spacing + 1e-9)) + 1
    ny = int(math.floor(spec.height / spec.spacing + 1e-9)) + 1
    return nx * ny


def estimate(spec: Surveillance, profile: Profile, travel: Travel) -> Estimate:
    """This robot's way to the nearest waypoint (where its share of the work starts)."""
    d = min(travel(float(x), float(y)) for x, y in spec.waypoints())
    if not math.isfinite(d):
        return Estimate(math.inf, math.inf)
    return Estimate(d, d / profile.speed)


def from_item(command: int, params: tuple[float, float, float, float], x: float, y: float) -> Surveillance:
    width, height, spacing, robots = params
    for name, v, lo in (("param1 (width, m)", width, 0.0), ("param2 (height, m)", height, 0.0)):
        if not (math.isfinite(v) and lo <= v <= MAX_SIDE):
            raise ValueError(f"{name}: expected a number 0..{MAX_SIDE:g}, got {v}")
    if not (math.isfinite(spacing) and 0 < spacing <= MAX_SIDE):
        raise ValueError(f"param3 (spacing, m): expected a number > 0 and <= {MAX_SIDE:g}, got {spacing}")
    if not (math.isfinite(robots) and float(robots).is_integer() and 0 <= robots <= 250):
        raise ValueError(f"param4 (robots): expected an integer 0..250, got {robots}")
    spec = Surveillance(x, y, float(width), float(height), float(spacing), int(robots))
    if count(spec) > MAX_WAYPOINTS:
        raise ValueError(f"{count(spec)} waypoints: expected at most {MAX_WAYPOINTS} (widen param3, the spacing)")
    return spec


def to_item(spec: Surveillance) -> tuple[int, tuple[float, float, float, float]]:
    return MAV_CMD_SPATIAL_USER_1, (float(spec.width), float(spec.height), float(spec.spacing), float(spec.robots))


@dataclass
class Board:
    """One robot's copy of a surveillance task's state: waypoints visited, and each robot's claim (the waypoint
    it heads for and when it claimed it).  A claim made earlier wins (ties: the lower robot id); visits and
    claims spread by broadcast status (:class:`~runtime.allocation.comutar.messages.CmSurvey`)."""
    points: np.ndarray
    me: int
    visited: set = field(default_factory=set)
    claims: dict = field(default_factory=dict)       # robot -> (waypoint, claimed at)
    target: int | None = None
    claimed_at: float = 0.0

    @property
    def complete(self) -> bool:
        return len(self.visited) >= len(self.points)

    def visit(self, i: int) -> bool:
        """Mark waypoint ``i`` visited; True if it was news."""
        if not 0 <= i < len(self.points) or i in self.visited:
            return False
        self.visited.add(i)
        if self.target == i:
            self.target = None
        return True

    def merge(self, robot: int, visited, target: int | None, claimed_at: float) -> bool:
        """A peer's status: its visits (waypoint indices), and its claim (None: it heads nowhere).  True if my
        target changed."""
        for i in set(visited).difference(self.visited):
            self.visit(i)
        if target is None or target in self.visited:
            self.claims.pop(robot, None)
        else:
            self.claims[robot] = (target, claimed_at)
        if self.target is not None and self._beaten(self.target):
            self.target = None
            return True
        return False

    def forget(self, robot: int) -> None:
        self.claims.pop(robot, None)

    def _beaten(self, i: int) -> bool:
        mine = (self.claimed_at, self.me)
        return any(w == i and (t, r) < mine for r, (w, t) in self.claims.items() if r != self.me)

    def choose(self, xy, now: float, switch: float | None = None) -> bool:
        """Claim the nearest waypoint neither visited nor claimed by another robot (Alg. 2 heads for the nearest
        waypoint at each instant: with ``switch`` (m), a held claim moves to a free waypoint nearer by more than
        that; None keeps it until visited).  When every open waypoint is claimed by another robot, claim nothing
        and wait (the first claimant wins; a lost claimant's claims are dropped).  True if the target changed."""
        if self.complete or (self.target is not None and switch is None):
            return False
        taken = {w for r, (w, _) in self.claims.items() if r != self.me}
        free = [i for i in range(len(self.points)) if i not in self.visited and i not in taken]
        if not free:
            return False
        d = np.hypot(*(self.points[free] - np.asarray(xy, float)).T)
        best = free[int(np.argmin(d))]
        if self.target is not None:
            mine = float(np.hypot(*(self.points[self.target] - np.asarray(xy, float))))
            if best == self.target or float(d.min()) >= mine - switch:
                return False
        self.target = best
        self.claimed_at = float(now)
        return True

    def point(self) -> tuple[float, float] | None:
        return None if self.target is None else (float(self.points[self.target, 0]), float(self.points[self.target, 1]))

    def clear_of(self, xy, clearance: float) -> tuple[float, float] | None:
        """Where a robot with no waypoint of its own (waiting) should stand aside to: a robot parked within
        ``clearance`` of an open waypoint keeps its claimant from ever reaching it (discs cannot overlap), so
        it backs off to ``clearance`` + 0.1 m from that waypoint, straight away from it.  None: it is clear
        (or it has a target, or nothing is open)."""
        if self.target is not None or self.complete:
            return None
        p = np.asarray(xy, float)
        open_ = [i for i in range(len(self.points)) if i not in self.visited]
        d = np.hypot(*(self.points[open_] - p).T)
        k = int(np.argmin(d))
        if d[k] >= clearance:
            return None
        w = self.points[open_[k]]
        away = (p - w) / d[k] if d[k] > 1e-9 else np.array([1.0, 0.0])
        q = w + away * (clearance + 0.1)
        return float(q[0]), float(q[1])

    def nearest_open(self, xy) -> float:
        """Distance (m) from ``xy`` to the nearest waypoint not visited (inf when none is left)."""
        open_ = [i for i in range(len(self.points)) if i not in self.visited]
        if not open_:
            return math.inf
        return float(np.min(np.hypot(*(self.points[open_] - np.asarray(xy, float)).T)))


@dataclass(frozen=True)
class Guidance:
    """What the allocation family tells a surveillance commitment's executor each cycle (data it writes; the
    executor never calls the agent)."""
    window: object                                 # runtime.control.cspace.Window: the robot's c-space
    target: tuple[float, float] | None             # the waypoint to head for; None: stay
    visited: frozenset | None                      # waypoints (indices) known visited; None: no board yet
    visit_radius: float                            # m: a waypoint this close counts as visited
    protected: bool                                # False: the robot must avoid obstacles and cannot; stand still
    obstacles: object                              # (M, 3) discs: every obstacle the robot knows (for detours)
