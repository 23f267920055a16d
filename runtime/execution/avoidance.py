"""Carry out an ``avoid_obstacles`` commitment (paper 003, Figs. 6-7): whichever actions of its coalition this
robot runs, as constraint functions over the next-frame window.

* ``obstacle_avoider`` (Alg. 4, on the robot kept clear): the obstacle list it works from is the guide's
  ``obstacles`` (the agent's input for it: this robot's own sensor, or the stream of the robot whose sensor it
  borrows).  When that is stale or missing the constraint allows only
  standing still: the robot stops at the next control cycle and stays stopped until the task has a provider
  again (the agent resigns the task when the provider is lost, and it is auctioned again).
* a ``*_reader`` keeping another robot's region in view (Alg. 3): the guide's ``region``.  A reader that has
  fallen behind (the region past ``far`` of its range) and gets no nearer takes a detour
  (:mod:`runtime.execution.detour`): Alg. 3's push toward the region and Alg. 4's from an obstacle between the
  two hold it still, and its consumer, whose region it no longer covers, stands still too.
* ``obstacle_detector`` alone: no motion constraint (the agent streams its output).
"""
from __future__ import annotations

import numpy as np

from runtime.control import cspace as C
from runtime.execution.cspace_vote import CspaceExecutor, stop_only
from runtime.execution.detour import Detour
from runtime.tasks import Commitment, Progress

MARGIN = 0.15        # m kept between the robot's body and an obstacle disc (pose errors between two robots' frames)
NEAR = 0.3           # m of clearance under which the avoider's heights fall (Alg. 4's dist_max)
LOOKAHEAD = 0.4      # m ahead of a candidate where its clearance is also judged (turning away counts)


class AvoidanceExecutor(CspaceExecutor):
    def __init__(self, commitment: Commitment, ctx):
        super().__init__(commitment, ctx)
        self.blind = False
        self.detour = Detour(ctx.log, f"avoid_obstacles {self.task.id} reader")

    def update(self, pose, now: float) -> list[Progress]:
        g = self.guide
        p = np.asarray([pose], float)
        cons = []
        if g.avoider is not None:
            obstacles = g.obstacles
            blind = obstacles is None
            if blind != self.blind:
                self.blind = blind
                self.ctx.log.warning("avoid_obstacles %d: %s", self.task.id,
                                     "no fresh obstacle data: stopping" if blind else "obstacle data again")
            if blind:
                cons.append(stop_only(self.window, "avoider without obstacle data"))
            else:
                c = C.avoid(self.window, p, obstacles, self.ctx.radius + MARGIN, near=NEAR, lookahead=LOOKAHEAD)
                c.weight = g.avoider
                cons.append(c)
        region = g.region
        if region is not None and g.reader is not None:
            sensor = g.sensor
            centre = region[1:3]
            goal = centre
            if np.hypot(centre[0] - pose[0], centre[1] - pose[1]) + region[3] > sensor.far * sensor.range:
                goal = self.detour.goal(pose, centre, now, lambda: g.obstacles_any)
            else:
                self._in_view(now)
            if goal != centre:
                c = C.survey(self.window, p, [goal])          # on a detour: out of view anyway
            else:
                c = C.sensor_view(self.window, p, [centre], region[3], sensor)
            c.weight = g.reader
            cons.append(c)
        else:
            self._in_view(now)
        self._cons = cons
        return []

    def _in_view(self, now: float) -> None:
        """No region out of view: no detour, and being stuck counts from now."""
        self.detour.held(now)
        self.detour.cancel()
