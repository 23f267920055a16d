"""Carry out a ``surveillance`` commitment (paper 003, Alg. 2): head for the waypoint the agent claimed, as a
constraint function over the next-frame window (no path: the survey's heights pull toward the waypoint, and
the robot's other commitments' constraints, obstacle avoidance above all, bound where it may go), and report
every open waypoint the robot comes within ``visit_radius`` of as ``visited``.

Alg. 2's pull toward the waypoint and Alg. 4's push from obstacles have local minima: a waypoint right behind an
obstacle holds the robot still in front of it.  A robot that gets no nearer its waypoint by ``PROGRESS`` m in
``STUCK_TIME`` s takes a detour: for up to ``DETOUR_TIME`` s it heads for a point ``DETOUR_REACH`` m away at
``DETOUR_ANGLE`` to the waypoint's bearing, on whichever side has more room from the obstacles it knows, then
heads for the waypoint again.

A robot that must avoid obstacles and cannot (its ``avoid_obstacles`` task not allocated yet, or the robot
whose sensor it borrows lost or silent: :meth:`ComutarAgent.protected`) does not survey: its constraint then
allows only standing still.
"""
from __future__ import annotations

import math

import numpy as np

from runtime.allocation.comutar import cspace as C
from runtime.allocation.comutar.protocol import VISITED
from runtime.execution.cspace_vote import CspaceExecutor, stop_only
from runtime.tasks import Commitment, Progress

STUCK_TIME = 4.0         # s without getting PROGRESS m nearer the waypoint: stuck
PROGRESS = 0.05          # m
DETOUR_TIME = 6.0        # s at most on a detour
DETOUR_REACH = 1.0       # m from where the robot was stuck to the detour point
DETOUR_ANGLE = math.radians(75.0)    # from the waypoint's bearing


class SurveillanceExecutor(CspaceExecutor):
    def __init__(self, commitment: Commitment, ctx):
        super().__init__(commitment, ctx)
        self.points = self.task.spec.waypoints()
        self.target: tuple[float, float] | None = None
        self.waiting = False              # for obstacle avoidance (not protected)
        self.detours = 0
        self._best: tuple[tuple | None, float, float] = (None, math.inf, 0.0)   # (target, least distance, since)
        self._detour: tuple[tuple[float, float], float] | None = None          # (point, until)

    def update(self, pose, now: float) -> list[Progress]:
        agent = self.agent
        out = []
        board = agent.boards.get(self.task.id)
        if board is not None:
            d = np.hypot(self.points[:, 0] - pose[0], self.points[:, 1] - pose[1])
            for i in np.flatnonzero(d <= agent.options.visit_radius):
                if int(i) not in board.visited:
                    out.append(Progress(self.task.id, VISITED, now, data={"waypoint": int(i)}))
        waiting = not agent.protected(now)
        if waiting != self.waiting:
            self.waiting = waiting
            self.ctx.log.info("surveillance %d: %s", self.task.id, "no obstacle avoidance: standing still" if waiting
                              else "obstacle avoidance running: surveying")
        self.target = agent.survey_target(self.task.id)
        if waiting:
            self._cons = [stop_only(self.window, "survey waits for obstacle avoidance")]
            self._best = (None, math.inf, now)
        else:
            goal = self._goal(pose, now)
            goal = np.full((1, 2), np.nan) if goal is None else np.asarray([goal], float)
            self._cons = [C.survey(self.window, np.asarray([pose], float), goal)]
        return out

    def _goal(self, pose, now: float) -> tuple[float, float] | None:
        """The waypoint, or the detour point while on a detour (see the module docstring)."""
        t = self.target
        if t is None:
            self._detour = None
            return None
        d = math.hypot(t[0] - pose[0], t[1] - pose[1])
        if self._detour is not None:
            (px, py), until = self._detour
            if now < until and math.hypot(px - pose[0], py - pose[1]) > 0.2:
                return self._detour[0]
            self._detour = None
            self._best = (t, d, now)
        target, best, since = self._best
        if target != t or d < best - PROGRESS:
            self._best = (t, d, now)
        elif now - since > STUCK_TIME:
            self._detour = (self._detour_point(pose, t, now), now + DETOUR_TIME)
            self.detours += 1
            self.ctx.log.info("surveillance %d: no nearer waypoint (%.1f, %.1f) in %.0f s: detour to (%.2f, %.2f)",
                              self.task.id, t[0], t[1], STUCK_TIME, *self._detour[0])
            return self._detour[0]
        return t

    def _detour_point(self, pose, t, now: float) -> tuple[float, float]:
        bearing = math.atan2(t[1] - pose[1], t[0] - pose[0])
        obstacles = self.agent.obstacle_input_any(now)
        best = None
        for side in (-1.0, 1.0):
            a = bearing + side * DETOUR_ANGLE
            p = (pose[0] + DETOUR_REACH * math.cos(a), pose[1] + DETOUR_REACH * math.sin(a))
            room = float(np.min(np.hypot(obstacles[:, 0] - p[0], obstacles[:, 1] - p[1]) - obstacles[:, 2])) \
                if len(obstacles) else math.inf
            if best is None or room > best[0]:
                best = (room, p)
        return best[1]
