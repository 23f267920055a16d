"""Pure pursuit path follower for a differential-drive (unicycle) base.

``PurePursuit(...).command((x, y, heading), path) -> (v, w, done)``: project the robot onto the path,
advance ``lookahead`` metres along it, steer on the arc through that point (curvature ``2*y_l/L^2`` in the
robot frame), slow down near the goal and for large heading errors, turn in place when the target is
behind, stop within ``goal_tolerance`` of the last waypoint.  Progress along the path is remembered so a
path that passes near itself is not short-cut; a different path resets it.
"""
from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from runtime.control import compiled
from runtime.errors import InputError

Pose = tuple[float, float, float]
Command = tuple[float, float, bool]


@dataclass
class PurePursuit:
    """Pure pursuit controller; speeds in m/s and rad/s, distances in metres."""
    lookahead: float = 0.4
    cruise_speed: float = 0.3
    max_turn_rate: float = 2.0
    goal_tolerance: float = 0.08
    slow_radius: float | None = None     # start slowing this far from the goal (default: 2 * lookahead)
    min_speed: float | None = None       # floor while approaching the goal (default: 0.15 * cruise_speed)
    turn_in_place: float = math.pi / 2   # heading error (rad) above which the robot turns on the spot
    _path: tuple = field(default=(), init=False, repr=False)
    _cum: np.ndarray = field(default_factory=lambda: np.zeros(1), init=False, repr=False)
    _pts: np.ndarray = field(default_factory=lambda: np.zeros((1, 2)), init=False, repr=False)
    _progress: float = field(default=0.0, init=False, repr=False)
    _fresh: bool = field(default=True, init=False, repr=False)
    _segs: tuple = field(default=(), init=False, repr=False)
    _lists: tuple = field(default=([0.0], [(0.0, 0.0)]), init=False, repr=False)    # _cum and _pts as floats

    def __post_init__(self) -> None:
        for name in ("lookahead", "cruise_speed", "max_turn_rate", "goal_tolerance"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise InputError(f"pure pursuit {name}: expected a finite number > 0, got {value!r}")
        if self.slow_radius is None:
            self.slow_radius = 2.0 * self.lookahead
        if self.min_speed is None:
            self.min_speed = 0.15 * self.cruise_speed
        if not 0 < self.turn_in_place <= math.pi:
            raise InputError(f"pure pursuit turn_in_place: expected an angle in (0, pi], got {self.turn_in_place!r}")

    def reset(self) -> None:
        """Forget the current path and the progress along it."""
        self._path = ()
        self._progress = 0.0
        self._fresh = True

    # ------------------------------------------------------------------ geometry
    def _set_path(self, path: Sequence[Sequence[float]]) -> None:
        key = tuple((float(p[0]), float(p[1])) for p in path)
        if not key:
            raise InputError("pure pursuit path: expected at least one (x, y) waypoint, got none")
        if key == self._path:
            return
        pts = np.asarray(key, dtype=float)
        if not np.all(np.isfinite(pts)):
            raise InputError("pure pursuit path: expected finite (x, y) waypoints, got NaN or inf")
        seg = np.hypot(*np.diff(pts, axis=0).T) if len(pts) > 1 else np.zeros(0)
        self._path, self._pts = key, pts
        self._cum = np.concatenate(([0.0], np.cumsum(seg)))
        self._lists = (self._cum.tolist(), [tuple(p) for p in pts.tolist()])
        self._progress = 0.0
        self._fresh = True
        # per-segment constants of the projection, computed once per path instead of every cycle
        a = pts[:-1]
        d = pts[1:] - a
        seg_len2 = np.einsum("ij,ij->i", d, d)
        seg_len = np.sqrt(seg_len2)
        self._segs = (a, d, np.where(seg_len2 > 0, seg_len2, 1.0), seg_len, np.where(seg_len > 0, seg_len, 1.0),
                      self._cum[:-1].copy(), self._cum[1:].copy())

    def _project(self, x: float, y: float) -> float:
        """Arc length of the closest path point; after the first call, only within a window around progress."""
        if len(self._pts) == 1:
            return 0.0
        a, d, len2_div, seg_len, len_div, start, end = self._segs
        if compiled.ENABLED:
            fresh, self._fresh = self._fresh, False
            return float(compiled.project(a, d, len2_div, seg_len, len_div, start, end, x, y, fresh,
                                          self._progress - self.lookahead, self._progress + 3.0 * self.lookahead,
                                          self.lookahead ** 2, self._progress))
        xy = np.array([x, y])
        t = np.einsum("ij,ij->i", xy - a, d) / len2_div
        t = np.minimum(np.maximum(t, 0.0), 1.0)
        s = start + t * seg_len
        if self._fresh:
            self._fresh = False
            return float(s[int(np.argmin(self._dist2(a, d, t, xy)))])
        # Tracking: prefer the part of the path in [progress - lookahead, progress + 3 * lookahead], so a
        # later leg that passes close by is not jumped to; if the robot is more than a lookahead away from
        # that window (pushed, pose jump), take the closest point anywhere ahead of progress - lookahead.
        lo, hi = self._progress - self.lookahead, self._progress + 3.0 * self.lookahead
        tw = np.minimum(np.maximum((np.minimum(np.maximum(s, lo), hi) - start) / len_div, 0.0), 1.0)
        dw = np.where((end < lo) | (start > hi), np.inf, self._dist2(a, d, tw, xy))
        i = int(np.argmin(dw))
        if dw[i] <= self.lookahead ** 2:
            return float(start[i] + tw[i] * seg_len[i])
        dist2 = np.where(s >= lo, self._dist2(a, d, t, xy), np.inf)
        i = int(np.argmin(dist2))
        return float(s[i]) if math.isfinite(dist2[i]) else self._progress

    @staticmethod
    def _dist2(a: np.ndarray, d: np.ndarray, t: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """Squared distance from ``xy`` to the point at fraction ``t`` of each segment (start ``a``, span ``d``)."""
        off = a + d * t[:, None] - xy
        return np.einsum("ij,ij->i", off, off)

    def _point_at(self, s: float) -> tuple[float, float]:
        cum, pts = self._lists                      # Python floats: a handful of scalars, no numpy calls
        if s >= cum[-1]:
            return pts[-1]
        i = bisect.bisect_right(cum, s) - 1
        i = min(max(i, 0), len(pts) - 2)
        span = cum[i + 1] - cum[i]
        t = 0.0 if span <= 0 else (s - cum[i]) / span
        (x0, y0), (x1, y1) = pts[i], pts[i + 1]
        return x0 + t * (x1 - x0), y0 + t * (y1 - y0)

    # ------------------------------------------------------------------ control
    def command(self, pose: Pose, path: Sequence[Sequence[float]]) -> Command:
        """Return (v, w, done) for the robot at ``pose`` = (x, y, heading) following ``path``."""
        x, y, heading = (float(c) for c in pose)
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(heading)):
            raise InputError(f"pure pursuit pose: expected finite (x, y, heading), got {tuple(pose)!r}")
        self._set_path(path)
        gx, gy = self._lists[1][-1]
        to_goal = math.hypot(gx - x, gy - y)
        if to_goal <= self.goal_tolerance:
            return 0.0, 0.0, True

        self._progress = max(self._progress, self._project(x, y))
        tx, ty = self._point_at(self._progress + self.lookahead)
        dx, dy = tx - x, ty - y
        c, s = math.cos(heading), math.sin(heading)
        xl, yl = c * dx + s * dy, -s * dx + c * dy
        l2 = xl * xl + yl * yl
        alpha = math.atan2(yl, xl)
        if abs(alpha) > self.turn_in_place or l2 <= 1e-12:
            return 0.0, math.copysign(self.max_turn_rate, alpha), False

        curvature = 2.0 * yl / l2
        goal_factor = min(1.0, to_goal / self.slow_radius)
        heading_factor = max(0.0, 1.0 - abs(alpha) / self.turn_in_place)
        v = self.cruise_speed * goal_factor * heading_factor
        v = max(v, min(self.min_speed, self.cruise_speed))
        if abs(curvature) * v > self.max_turn_rate:
            v = self.max_turn_rate / abs(curvature)
        return v, curvature * v, False
