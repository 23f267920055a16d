"""The toy method's one message."""
from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class ToyClaim:
    sender: int
    dest: int
    task: int
    cost: float

    def invalid(self) -> str | None:
        if not (1 <= self.task >> 16 <= 250):
            return f"task {self.task}: expected a fleet task id"
        if not (math.isfinite(self.cost) and self.cost >= 0):
            return f"cost {self.cost}: expected a finite amount >= 0"
        return None
