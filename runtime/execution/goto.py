"""Drive to a point: plan, follow the path with pure pursuit (votes in the arbiter), re-plan after a bump or
when pushed off station, report ``arrived`` once there and ``done`` after the task's hold time (never, for
station keeping)."""
from __future__ import annotations

import math

from runtime.control.behaviours import FollowPath
from runtime.execution.executor import Executor
from runtime.tasks import ARRIVED, DONE, Commitment, Progress


class GotoExecutor(Executor):
    def __init__(self, commitment: Commitment, ctx):
        super().__init__(commitment, ctx)
        self.goal = self.task.position
        self.hold = self.finishes_after(self.task)
        self.follow = FollowPath(follower=ctx.pursuit())
        self.arrived_at: float | None = None
        self.finished = False
        self._planned = False

    @staticmethod
    def finishes_after(task) -> float | None:
        """Seconds after arrival at which this executor reports the task done (None: never)."""
        return task.spec.hold

    @property
    def behaviours(self) -> list:
        return [self.follow]

    def _plan(self, pose) -> None:
        self.follow.set_path(self.ctx.planner.route(pose, self.goal))

    def begin(self, pose, now: float) -> None:
        """Before the sensors are read: the first plan, or a new one if pushed off station."""
        if not self._planned:
            self._planned = True
            self._plan(pose)
            self.ctx.log.info("driving to task %d at (%.2f, %.2f)", self.task.id, *self.goal)
        elif self.follow.done and math.hypot(self.goal[0] - pose[0], self.goal[1] - pose[1]) > 3 * self.ctx.goal_tolerance:
            self._plan(pose)                    # pushed off station: go back

    def bump_ended(self, pose, now: float) -> None:
        self._plan(pose)                        # re-plan from where the bump left us

    def update(self, pose, now: float) -> list[Progress]:
        self.follow.update(pose, now)
        out = []
        if self.follow.done and self.arrived_at is None:
            self.arrived_at = now
            out.append(Progress(self.task.id, ARRIVED, now))
        if (not self.finished and self.arrived_at is not None and self.hold is not None
                and now - self.arrived_at >= self.hold):
            self.finished = True
            out.append(Progress(self.task.id, DONE, now))
        return out

    def cancel(self, now: float) -> None:
        self.follow.set_path(None)
