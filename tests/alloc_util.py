"""Helpers of the allocation tests that feed agents by hand."""
from __future__ import annotations

import math
from typing import Callable

from runtime.tasks import Estimate, Profile
from runtime.tasks import estimate as task_estimate


class StraightLineEstimator:
    """The agent's estimator for a point robot: straight-line travel from its current position."""

    def __init__(self, profile: Profile, pose: Callable[[], tuple[float, float] | None]):
        self.profile = profile
        self.pose = pose

    def estimates(self, tasks) -> list[Estimate]:
        p = self.pose()
        if p is None:
            return [Estimate(math.inf, math.inf) for _ in tasks]
        return [task_estimate(t, self.profile, lambda x, y: math.hypot(x - p[0], y - p[1])) for t in tasks]
