"""Carry out a ``surveillance`` commitment (paper 003, Alg. 2): head for the waypoint the agent claimed, as a
constraint function over the next-frame window (no path: the survey's heights pull toward the waypoint, and
the robot's other commitments' constraints, obstacle avoidance above all, bound where it may go), and report
every open waypoint the robot comes within ``visit_radius`` of as ``visited``.

Alg. 2's pull toward the waypoint and Alg. 4's push from obstacles have local minima: a robot stuck in front of
an obstacle takes a detour (:mod:`runtime.execution.detour`).

A robot that must avoid obstacles and cannot (its ``avoid_obstacles`` task not allocated yet, or the robot
whose sensor it borrows lost or silent) does not survey: its constraint then allows only standing still.  What the
agent wants (the target, the waypoints known visited, whether the robot is protected, the obstacles it knows) comes
each cycle as :class:`runtime.tasks.surveillance.Guidance` in ``guide``.
"""
from __future__ import annotations

import numpy as np

from runtime.control import cspace as C
from runtime.execution.cspace_vote import CspaceExecutor, stop_only
from runtime.execution.detour import Detour
from runtime.tasks import Commitment, Progress
from runtime.tasks.surveillance import VISITED


class SurveillanceExecutor(CspaceExecutor):
    def __init__(self, commitment: Commitment, ctx):
        super().__init__(commitment, ctx)
        self.points = self.task.spec.waypoints()
        self.target: tuple[float, float] | None = None
        self.waiting = False              # for obstacle avoidance (not protected)
        self.detour = Detour(ctx.log, f"surveillance {self.task.id}")

    def update(self, pose, now: float) -> list[Progress]:
        g = self.guide
        out = []
        if g.visited is not None:
            d = np.hypot(self.points[:, 0] - pose[0], self.points[:, 1] - pose[1])
            for i in np.flatnonzero(d <= g.visit_radius):
                if int(i) not in g.visited:
                    out.append(Progress(self.task.id, VISITED, now, data={"waypoint": int(i)}))
        waiting = not g.protected
        if waiting != self.waiting:
            self.waiting = waiting
            self.ctx.log.info("surveillance %d: %s", self.task.id, "no obstacle avoidance: standing still" if waiting
                              else "obstacle avoidance running: surveying")
        self.target = g.target
        if waiting:
            self._cons = [stop_only(self.window, "survey waits for obstacle avoidance")]
            self.detour.held(now)
        else:
            if self.target is None:
                self.detour.cancel()
                goal = np.full((1, 2), np.nan)
            else:
                goal = np.asarray([self.detour.goal(pose, self.target, now, lambda: g.obstacles)])
            self._cons = [C.survey(self.window, np.asarray([pose], float), goal)]
        return out
