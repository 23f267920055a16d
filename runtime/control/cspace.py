"""The allowed configuration space of paper 003 (Section 2.1.3, Algs. 2-4) as weighted grids of next-frame
configurations, and the choice of a motor command from them.

**The window.**  The c-space is evaluated for the next time frame only: a 0.1 x 0.1 m window (``half`` =
0.05 m) of ``cells`` x ``cells`` cells (21 x 21: 5 mm) around the robot, and a frame period ``T_f`` such that
``half / T_f`` is the top speed ``v_max`` (0.2 s at 0.25 m/s).  Velocity is constant over a frame, so each
command (v, w) of a differential drive reaches one configuration.  Every cell centre (robot frame, x ahead,
y left: the window turns with the robot, so the map is computed once) is reached by exactly one arc::

    heading change a = 2 atan(dy / dx),  w = a / T_f,  v = sign(dx) * chord * (a / 2) / sin(a / 2) / T_f

and the cells whose arc exceeds ``v_max`` or ``w_max`` are dropped (only two narrow cones, ahead and behind,
remain).  A differential drive also turns in place: those configurations all sit in the centre cell and
differ only in heading, so the window adds ``rotations`` of them (v = 0, w from -w_max to w_max, stop
among them).  These are the *candidates*: arrays ``v``, ``w``, ``dx``, ``dy``, ``dth`` and the ``cell`` each
falls in, precomputed once per :class:`Window`.

**Constraint functions** return a :class:`Constraint` over the candidates: an allowed mask (None: forbids
nothing) and heights (None: no preference).  Every function takes a batch of robots: poses of shape
``(n, 3)`` (x, y, heading in the fleet frame) and returns ``(n, C)`` arrays, so a simulation evaluates a
whole fleet in one call.

* :func:`survey` (Alg. 2): height ``k (1 - dist / dist0)`` toward the waypoint; never forbids.
* :func:`sensor_view` (Alg. 3): a conical sensor (field of view ``fov``, range ``rng``) keeping a disc
  region in view: a candidate may not take the region past a border margin or beyond ``far * rng`` when it
  is within them now, nor further out when it is already beyond; weak heights pull it back to the centre.
* :func:`avoid` (Alg. 4): forbids moving into obstacles; near one prefers clearance, elsewhere small moves.
* :func:`band` (Fig. 1's controller): only commands within a disturbance around an optimal (v, w).

**Choosing** (:func:`choose`): the allowed set is the intersection of every mask (the c-space's compound
operator); if it is empty the robot stops and the choice reports the conflict.  Each function's heights are
brought to one scale (Alg. 2's raw heights shrink as 1 / dist0, so they are normalised to [0, 1] over the
allowed candidates; Alg. 4's have a fixed scale, 2k) and summed with per-action weights; the command is the
best candidate, ties to the one nearest the centre.  :func:`to_arc_ballot` turns a choice into votes and vetoes
over the DAMN arbiter's arc set (phase 2).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Sequence

import numpy as np

from runtime.errors import InputError

TAU = 2.0 * math.pi


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def wrap(a):
    """Angles into (-pi, pi]."""
    return np.pi - np.mod(np.pi - a, TAU)


@dataclass(frozen=True)
class Window:
    """One robot's next-frame window and its candidate configurations (see the module docstring)."""
    v_max: float = 0.25            # m/s: top speed; the frame period is half / v_max
    w_max: float = 2.0             # rad/s
    cells: int = 21                # per side (odd: a centre cell)
    half: float = 0.05             # m: half the window side
    rotations: int = 9             # in-place turn rates at the centre cell, stop included (odd)

    def __post_init__(self) -> None:
        for name in ("v_max", "w_max", "half"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"c-space window {name}: expected a finite number > 0, got {v!r}")
        for name in ("cells", "rotations"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 3 and v % 2 == 1):
                raise InputError(f"c-space window {name}: expected an odd integer >= 3, got {v!r}")

    @property
    def period(self) -> float:
        """T_f (s): the frame period, half / v_max."""
        return self.half / self.v_max

    @property
    def cell_size(self) -> float:
        return 2.0 * self.half / self.cells

    @cached_property
    def cell_xy(self) -> np.ndarray:
        """Centres of every cell (cells**2, 2), robot frame; cell k = (row k // cells: x, column k % cells: y)."""
        c = (np.arange(self.cells) - self.cells // 2) * self.cell_size
        gx, gy = np.meshgrid(c, c, indexing="ij")
        return _frozen(np.stack([gx.ravel(), gy.ravel()], axis=1))

    @cached_property
    def _candidates(self) -> dict[str, np.ndarray]:
        T = self.period
        xy = self.cell_xy
        dx, dy = xy[:, 0], xy[:, 1]
        moving = np.abs(dx) > 1e-12
        a = np.zeros(len(xy))
        a[moving] = 2.0 * np.arctan(dy[moving] / dx[moving])
        chord = np.hypot(dx, dy)
        half_a = a / 2.0
        ratio = np.ones_like(a)
        nz = np.abs(half_a) > 1e-12
        ratio[nz] = half_a[nz] / np.sin(half_a[nz])
        v = np.sign(dx) * chord * ratio / T
        w = a / T
        tol = 1.0 + 1e-9
        keep = moving & (np.abs(v) <= self.v_max * tol) & (np.abs(w) <= self.w_max * tol)
        cells = np.flatnonzero(keep)
        centre = (self.cells * self.cells) // 2
        rot_w = np.linspace(-self.w_max, self.w_max, self.rotations)
        out = {
            "v": np.concatenate([v[cells], np.zeros(self.rotations)]),
            "w": np.concatenate([w[cells], rot_w]),
            "dx": np.concatenate([dx[cells], np.zeros(self.rotations)]),
            "dy": np.concatenate([dy[cells], np.zeros(self.rotations)]),
            "dth": np.concatenate([a[cells], rot_w * T]),
            "cell": np.concatenate([cells, np.full(self.rotations, centre)]),
        }
        return {k: _frozen(x) for k, x in out.items()}

    @property
    def v(self) -> np.ndarray:
        return self._candidates["v"]

    @property
    def w(self) -> np.ndarray:
        return self._candidates["w"]

    @property
    def dx(self) -> np.ndarray:
        return self._candidates["dx"]

    @property
    def dy(self) -> np.ndarray:
        return self._candidates["dy"]

    @property
    def dth(self) -> np.ndarray:
        return self._candidates["dth"]

    @property
    def cell(self) -> np.ndarray:
        """The window cell (index into :attr:`cell_xy`) of every candidate."""
        return self._candidates["cell"]

    @property
    def size(self) -> int:
        """C: the number of candidates."""
        return len(self.v)

    @cached_property
    def stop(self) -> int:
        """The candidate (0, 0)."""
        return int(np.flatnonzero((self.v == 0) & (self.w == 0))[0])

    @cached_property
    def displacement(self) -> np.ndarray:
        """How far each candidate moves the robot (m), plus a hair per radian turned: the tie-break order."""
        return _frozen(np.hypot(self.dx, self.dy) + 1e-6 * np.abs(self.dth))

    def configurations(self, poses) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Next-frame configurations of every candidate for a batch of poses (n, 3): x, y, heading (n, C)."""
        p = np.asarray(poses, dtype=float).reshape(-1, 3)
        c, s = np.cos(p[:, 2:3]), np.sin(p[:, 2:3])
        x = p[:, 0:1] + c * self.dx - s * self.dy
        y = p[:, 1:2] + s * self.dx + c * self.dy
        return x, y, p[:, 2:3] + self.dth

    def grid(self, values: np.ndarray, fill: float = np.nan) -> np.ndarray:
        """One robot's per-candidate values as the cells x cells window (the best value of the candidates in a
        cell; cells no candidate reaches hold ``fill``): what Fig. 1 draws.  Row = x (ahead), column = y."""
        out = np.full(self.cells * self.cells, -np.inf)
        np.maximum.at(out, self.cell, np.asarray(values, dtype=float))
        out[np.isneginf(out)] = fill
        return out.reshape(self.cells, self.cells)


@dataclass
class Constraint:
    """One action's constraint over a batch: allowed (n, C) bool or None; heights (n, C) or None."""
    allowed: np.ndarray | None = None
    height: np.ndarray | None = None
    name: str = ""
    weight: float = 1.0
    scale: float | None = None       # heights divided by this before weighting; None: by their span (per robot)


# ---------------------------------------------------------------------- Alg. 2: survey

def survey(win: Window, poses, targets, k: float = 1.0, turn_weight: float = 1.5) -> Constraint:
    """Alg. 2 for a batch: every candidate weighted ``k (1 - dist / dist0)`` by how near it is to the robot's
    waypoint (``targets`` (n, 2); NaN: no waypoint, no preference).  The distance from a *pose* counts the
    turn a differential drive still needs to face the waypoint: ``|p - g| + turn_weight * (v_max / w_max) *
    |bearing error|`` (with position alone, reversing toward a waypoint behind beats turning to face it).
    ``dist0`` is that of the current pose.  Never forbids."""
    p = np.asarray(poses, dtype=float).reshape(-1, 3)
    g = np.asarray(targets, dtype=float).reshape(-1, 2)
    metres_per_rad = turn_weight * win.v_max / win.w_max
    x, y, th = win.configurations(p)

    def dist(px, py, pth):
        ex, ey = g[:, 0:1] - px, g[:, 1:2] - py
        return np.hypot(ex, ey) + metres_per_rad * np.abs(wrap(np.arctan2(ey, ex) - pth))

    d0 = dist(p[:, 0:1], p[:, 1:2], p[:, 2:3])
    h = k * (1.0 - dist(x, y, th) / np.where(d0 > 1e-9, d0, 1.0))
    h = np.where(np.isfinite(d0) & (d0 > 1e-9), h, 0.0)
    return Constraint(None, h, "survey")


# ---------------------------------------------------------------------- Alg. 3: sensor reader

@dataclass(frozen=True)
class Sensor:
    """A conical sensor looking along the robot's heading (a laser: 180 deg, 8 m; a sonar ring: 360 deg)."""
    fov: float = math.pi                 # rad, full angle
    range: float = 8.0                   # m
    border: float = math.radians(10.0)   # rad: a region this close to an FOV edge is "close to the border"
    far: float = 0.8                     # a region beyond far * range is "too far"

    def sees(self, pose, point, radius: float = 0.0) -> bool:
        """Is the disc (``point``, ``radius``) within the margins of the view from ``pose``?"""
        b, d = bearing_distance(np.asarray(pose, float)[None, :], np.asarray(point, float)[None, :])
        return bool(_within(self, b, d, radius)[0, 0])

    def covers(self, pose, point, radius: float = 0.0) -> bool:
        """Does the view from ``pose`` take in all of the disc (``point``, ``radius``), to the sensor's full range
        and angle (no margins)?  What a robot streaming this sensor's data to another can vouch for."""
        b, d = bearing_distance(np.asarray(pose, float)[None, :], np.asarray(point, float)[None, :])
        b, d = abs(float(b[0, 0])), float(d[0, 0])
        if d + radius > self.range:
            return False
        if self.fov >= TAU - 1e-9:
            return True
        return d > radius and b + math.asin(radius / d) <= self.fov / 2.0


def bearing_distance(poses, points, x=None, y=None, th=None):
    """Bearing (in the heading's frame) and distance of each robot's ``points`` (n, 2) from its pose, or from
    the configurations (x, y, th) (n, C) when given."""
    p = np.asarray(poses, dtype=float).reshape(-1, 3)
    q = np.asarray(points, dtype=float).reshape(-1, 2)
    if x is None:
        x, y, th = p[:, 0:1], p[:, 1:2], p[:, 2:3]
    ex, ey = q[:, 0:1] - x, q[:, 1:2] - y
    return wrap(np.arctan2(ey, ex) - th), np.hypot(ex, ey)


def _within(sensor: Sensor, b, d, radius) -> np.ndarray:
    half = sensor.fov / 2.0
    ok_angle = np.abs(b) <= half - sensor.border if sensor.fov < TAU - 1e-9 else np.ones_like(b, bool)
    return ok_angle & (d + radius <= sensor.far * sensor.range)


def _keep_or_improve(after, now, limit):
    """Within ``limit`` now: stay within it.  Past it (the region drifted out): get back within it if some
    candidate can, else get strictly better."""
    back = after <= limit + 1e-12
    return np.where(now <= limit, back, np.where(back.any(axis=1, keepdims=True), back, after < now - 1e-9))


def sensor_view(win: Window, poses, regions, radius, sensor: Sensor, pull: float = 1.0) -> Constraint:
    """Alg. 3, defined geometrically, for a batch: keep each robot's region (``regions`` (n, 2) centres of discs
    of ``radius`` (n,) or scalar; NaN: no region) in the sensor's view.

    A candidate is forbidden if it takes the region's bearing past ``fov / 2 - border`` while it is within
    that now (turning away from a region near an FOV border), or does not bring it back when the region has
    drifted past; likewise for the distance (plus the radius) and ``far * range`` (moving away from a region
    too far).  When no candidate brings a drifted region back, only those that do not make it worse are
    allowed; stopping is always among them, so the mask alone is never empty.  The heights (``pull``; the paper's
    Alg. 3 has none) favour re-centring and approaching, so a reader with no other motion task brings a region
    that drifts back into view."""
    p = np.asarray(poses, dtype=float).reshape(-1, 3)
    g = np.asarray(regions, dtype=float).reshape(-1, 2)
    r = np.broadcast_to(np.asarray(radius, dtype=float), (len(p),))[:, None]
    x, y, th = win.configurations(p)
    b0, d0 = bearing_distance(p, g)
    b1, d1 = bearing_distance(p, g, x, y, th)
    half = sensor.fov / 2.0
    far = sensor.far * sensor.range
    strict = _keep_or_improve(d1 + r, d0 + r, far)
    loose = d1 + r <= np.maximum(far, d0 + r) + 1e-12
    if sensor.fov < TAU - 1e-9:
        strict &= _keep_or_improve(np.abs(b1), np.abs(b0), half - sensor.border)
        loose &= np.abs(b1) <= np.maximum(half - sensor.border, np.abs(b0)) + 1e-12
    allowed = np.where(strict.any(axis=1, keepdims=True), strict, loose)
    height = -np.abs(b1) / max(half, 1e-9) - np.maximum(0.0, d1 + r - far) / sensor.range
    none = ~np.isfinite(g).all(axis=1)
    allowed[none] = True
    height[none] = 0.0
    return Constraint(allowed, pull * height, "sensor")


# ---------------------------------------------------------------------- Alg. 4: obstacle avoider

def clearance(win: Window, poses, obstacles, robot_radius, ignore=None, lookahead: float = 0.0):
    """Distance (m) from the robot's disc to the nearest obstacle disc: at the current poses (n, 1) and at every
    candidate (n, C); with ``lookahead`` > 0, at the point that far ahead of each candidate along its heading.
    ``obstacles`` (M, 3) x, y, radius; ``ignore`` (n, M) bool masks obstacles a robot does not see (itself,
    out of range).  inf where nothing is seen."""
    p = np.asarray(poses, dtype=float).reshape(-1, 3)
    ob = np.asarray(obstacles, dtype=float).reshape(-1, 3)
    n = len(p)
    if len(ob) == 0:
        return np.full((n, 1), np.inf), np.full((n, win.size), np.inf)
    x, y, th = win.configurations(p)
    if lookahead:
        x, y = x + lookahead * np.cos(th), y + lookahead * np.sin(th)
    rr = np.broadcast_to(np.asarray(robot_radius, dtype=float), (n,))[:, None]
    gap = ob[None, :, 2] + rr                                           # (n, M)
    c0 = np.hypot(p[:, 0:1] - ob[None, :, 0], p[:, 1:2] - ob[None, :, 1]) - gap
    c1 = np.hypot(x[:, :, None] - ob[None, None, :, 0], y[:, :, None] - ob[None, None, :, 1]) - gap[:, None, :]
    if ignore is not None:
        c0 = np.where(ignore, np.inf, c0)
        c1 = np.where(ignore[:, None, :], np.inf, c1)
    return c0.min(axis=1, keepdims=True), c1.min(axis=2)


def avoid(win: Window, poses, obstacles, robot_radius, ignore=None, k: float = 1.0, near: float = 0.5,
          margin: float = 0.02, lookahead: float = 1.0, rest: float = 0.0) -> Constraint:
    """Alg. 4 for a batch (obstacles as discs, see :func:`clearance`):

    * inside an obstacle (clearance below ``margin``): forbidden, unless the candidate gains clearance (a robot
      already too close may back out; stopping is always allowed);
    * near one (clearance within ``near``, the paper's dist_max): height ``k * clearance / near``;
    * elsewhere: ``k (1 - rest * dist2 / dist2_max)``, dist2 the candidate's displacement and dist2_max the
      window's half-diagonal: small moves preferred.

    Three departures from the printed formulas, each because the printed one leaves a robot stuck in front of
    an obstacle: the clearance of a *pose* is the smaller of that at the candidate and at ``lookahead`` metres
    ahead along its heading (with the position alone, turning away from an obstacle in front gains nothing
    within one frame); the free-space height is k, not 2k, so that it meets the near-obstacle height at
    ``near`` (a jump from k to 2k there is a wall the robot will not cross); and ``rest`` (the paper: 1)
    is 0 by default: at 1 a full step costs 0.7 of the scale, more than any progress of the survey, and even a
    little of it tips the balance between turning away from an obstacle and back toward the waypoint into
    turning on the spot; "small moves preferred" is left to :func:`choose`'s tie-break (least displacement).
    The heights are on the fixed scale k (:attr:`Constraint.scale`).  Like any sum of attraction and
    repulsion evaluated one frame ahead, this has local minima: a waypoint right behind a wide obstacle can
    hold the robot still in front of it (a planner's path, phase 2, is the cure)."""
    c0, c1 = clearance(win, poses, obstacles, robot_radius, ignore)
    allowed = ~((c1 < margin) & (c1 < c0 - 1e-12))
    c = c1
    if lookahead:
        c = np.minimum(c1, clearance(win, poses, obstacles, robot_radius, ignore, lookahead)[1])
    dist2 = np.hypot(win.dx, win.dy)[None, :]
    free = k * (1.0 - rest * dist2 / (math.sqrt(2.0) * win.half))
    height = np.where(c < near, k * np.maximum(c, 0.0) / near, free)
    return Constraint(allowed, height, "avoid", scale=k)


# ---------------------------------------------------------------------- Fig. 1: a controller with a disturbance

def band(win: Window, v: float, w: float, dv: float, dw: float, n: int = 1) -> Constraint:
    """A controller's optimal output (v, w) plus a disturbance: the allowed commands (Fig. 1, dark grey)."""
    ok = (np.abs(win.v - v) <= dv + 1e-12) & (np.abs(win.w - w) <= dw + 1e-12)
    h = -(np.abs(win.v - v) / max(dv, 1e-9) + np.abs(win.w - w) / max(dw, 1e-9))
    return Constraint(np.broadcast_to(ok, (n, win.size)).copy(), np.broadcast_to(h, (n, win.size)).copy(), "band")


# ---------------------------------------------------------------------- intersection, then maximisation

@dataclass
class Choice:
    """The commands chosen for a batch: (n,) arrays; ``conflict`` where nothing was allowed (the robot stops)."""
    v: np.ndarray
    w: np.ndarray
    index: np.ndarray
    allowed: np.ndarray                   # (n, C) the intersection
    score: np.ndarray                     # (n, C) in [0, 1] over allowed, -inf elsewhere
    conflict: np.ndarray                  # (n,) bool
    blame: list = field(default_factory=list)    # per robot: names of the masks whose intersection is empty


def normalise(h: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """Heights scaled to [0, 1] over each robot's allowed candidates (0 where flat)."""
    masked_hi = np.where(allowed, h, -np.inf).max(axis=1, keepdims=True)
    masked_lo = np.where(allowed, h, np.inf).min(axis=1, keepdims=True)
    span = masked_hi - masked_lo
    ok = np.isfinite(span) & (span > 1e-12)
    return np.where(ok, (h - np.where(ok, masked_lo, 0.0)) / np.where(ok, span, 1.0), 0.0)


def intersect(win: Window, constraints: Sequence[Constraint], n: int) -> np.ndarray:
    allowed = np.ones((n, win.size), dtype=bool)
    for c in constraints:
        if c.allowed is not None:
            allowed &= c.allowed
    return allowed


def choose(win: Window, constraints: Sequence[Constraint], n: int = 1) -> Choice:
    """Intersect every mask; sum the normalised, weighted heights over what is left; take the best candidate
    (ties: least displacement).  A robot with nothing allowed stops (``conflict``)."""
    allowed = intersect(win, constraints, n)
    total = np.zeros((n, win.size))
    for c in constraints:
        if c.height is not None and c.weight:
            total += c.weight * (normalise(c.height, allowed) if c.scale is None else c.height / c.scale)
    score = normalise(total, allowed)
    score = np.where(allowed, score, -np.inf)
    best = score.max(axis=1, keepdims=True)
    tied = allowed & (score >= best - 1e-9)
    order = np.where(tied, win.displacement[None, :], np.inf)
    idx = np.argmin(order, axis=1)
    conflict = ~allowed.any(axis=1)
    idx = np.where(conflict, win.stop, idx)
    blame = [[] for _ in range(n)]
    for i in np.flatnonzero(conflict):
        blame[i] = [c.name for c in constraints if c.allowed is not None and not c.allowed[i].all()]
    return Choice(win.v[idx], win.w[idx], idx, allowed, score, conflict, blame)


def to_arc_ballot(win: Window, choice: Choice, arcs, robot: int = 0, reach: float = 1.5):
    """One robot's choice as the DAMN arbiter's votes and vetoes over ``arcs`` (an ``ArcSet``: ``.v``, ``.w``):
    each arc takes the score of the nearest candidate in (v / v_max, w / w_max); votes 2 score - 1 in [-1, 1];
    an arc is vetoed when that candidate is not allowed, or when no candidate lies within ``reach`` candidate
    spacings of it (it leaves the window).  A conflict (nothing allowed), or nothing allowed but standing
    still, vetoes every arc but stop (turning on the spot included)."""
    av, aw = np.asarray(arcs.v, float), np.asarray(arcs.w, float)
    cv, cw = win.v / win.v_max, win.w / win.w_max
    d = np.hypot(av[:, None] / win.v_max - cv[None, :], aw[:, None] / win.w_max - cw[None, :])
    near = np.argmin(d, axis=1)
    spacing = 2.0 / (win.cells - 1)
    allowed = choice.allowed[robot]
    score = choice.score[robot]
    veto = ~allowed[near] | (d[np.arange(len(av)), near] > reach * spacing)
    # an arc between candidates keeps its nearest candidate's vote (vetoed all the same): the arbiter smooths votes
    # over neighbouring arcs, and -1 on every arc between the sparse candidates would drown the best of them
    votes = np.where(~allowed[near], -1.0, 2.0 * np.where(np.isfinite(score[near]), score[near], 0.0) - 1.0)
    if choice.conflict[robot] or not allowed[np.arange(len(allowed)) != win.stop].any():
        stop = (av == 0) & (aw == 0)
        veto = ~stop
        votes = np.where(stop, 1.0, -1.0)
    return votes, veto


def advance(poses, v, w, dt: float) -> np.ndarray:
    """Poses (n, 3) after driving (v, w) (n,) for ``dt`` seconds on exact arcs (a differential drive)."""
    p = np.asarray(poses, dtype=float).reshape(-1, 3)
    v = np.asarray(v, dtype=float).reshape(-1)
    w = np.asarray(w, dtype=float).reshape(-1)
    a = w * dt
    small = np.abs(a) < 1e-9
    safe = np.where(small, 1.0, w)
    fx = np.where(small, v * dt, v / safe * np.sin(a))
    fy = np.where(small, 0.0, v / safe * (1.0 - np.cos(a)))
    c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
    return np.stack([p[:, 0] + c * fx - s * fy, p[:, 1] + s * fx + c * fy, wrap(p[:, 2] + a)], axis=1)
