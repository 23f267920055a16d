"""Getting out of the local minima of a pull toward a point and a push from obstacles (paper 003's Alg. 2 and
Alg. 4, or Alg. 3 and Alg. 4): a robot with an obstacle between it and where it is pulled stands still in front
of it.  A robot that gets no nearer its target by ``PROGRESS`` m in ``STUCK_TIME`` s takes a detour: for up to
``DETOUR_TIME`` s it heads for a point ``DETOUR_REACH`` m away at ``DETOUR_ANGLE`` to the target's bearing, on
whichever side has more room from the obstacles it knows, then heads for the target again.
"""
from __future__ import annotations

import math

import numpy as np

STUCK_TIME = 4.0         # s without getting PROGRESS m nearer the target: stuck
PROGRESS = 0.05          # m
DETOUR_TIME = 6.0        # s at most on a detour
DETOUR_REACH = 1.0       # m from where the robot was stuck to the detour point
DETOUR_ANGLE = math.radians(75.0)    # from the target's bearing
ARRIVED = 0.2            # m from the detour point: the detour is over


class Detour:
    """One robot's detours toward one changing target (:meth:`goal` each control cycle)."""

    def __init__(self, log, what: str):
        self.log, self.what = log, what       # ``what``: how the log names the pull ("surveillance 65540")
        self.count = 0
        self._best: tuple[tuple | None, float, float] = (None, math.inf, 0.0)   # (target, least distance, since)
        self._detour: tuple[tuple[float, float], float] | None = None          # (point, until)

    def held(self, now: float) -> None:
        """The robot is held still (not by its own pull): being stuck starts counting again."""
        self._best = (None, math.inf, now)

    def cancel(self) -> None:
        """No target: a detour under way ends."""
        self._detour = None

    def goal(self, pose, target: tuple[float, float], now: float, obstacles) -> tuple[float, float]:
        """Where to head now: ``target``, or the detour point while on a detour.  ``obstacles()``: the (M, 3) discs
        the robot knows, read only when a detour starts."""
        t = tuple(target)
        d = math.hypot(t[0] - pose[0], t[1] - pose[1])
        if self._detour is not None:
            (px, py), until = self._detour
            if now < until and math.hypot(px - pose[0], py - pose[1]) > ARRIVED:
                return self._detour[0]
            self._detour = None
            self._best = (t, d, now)
        best_target, best, since = self._best
        if best_target != t or d < best - PROGRESS:
            self._best = (t, d, now)
        elif now - since > STUCK_TIME:
            self._detour = (self._point(pose, t, obstacles()), now + DETOUR_TIME)
            self.count += 1
            self.log.info("%s: no nearer (%.1f, %.1f) in %.0f s: detour to (%.2f, %.2f)",
                          self.what, t[0], t[1], STUCK_TIME, *self._detour[0])
            return self._detour[0]
        return t

    @staticmethod
    def _point(pose, t, obstacles) -> tuple[float, float]:
        bearing = math.atan2(t[1] - pose[1], t[0] - pose[0])
        best = None
        for side in (-1.0, 1.0):
            a = bearing + side * DETOUR_ANGLE
            p = (pose[0] + DETOUR_REACH * math.cos(a), pose[1] + DETOUR_REACH * math.sin(a))
            room = float(np.min(np.hypot(obstacles[:, 0] - p[0], obstacles[:, 1] - p[1]) - obstacles[:, 2])) \
                if len(obstacles) else math.inf
            if best is None or room > best[0]:
                best = (room, p)
        return best[1]
