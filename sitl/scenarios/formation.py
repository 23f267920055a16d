"""Formation (paper 002): the operator hands the fleet one station-keeping position per robot at t = 0
(MAV_CMD_NAV_LOITER_UNLIM items); the goal is met when every position is held by a distinct live robot
that stands on it."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Optional

from runtime.config.build import ConfigError, rng


@dataclass(frozen=True)
class Config:
    type: Literal["formation"] = "formation"
    positions: tuple[tuple[float, float], ...] = ()     # m, fleet frame
    to: Optional[int] = None                            # robot the operator uploads to (null: the lowest id)
    tolerance: float = field(default=0.2, metadata=rng(0.01, 10.0))    # m: a robot is on its position

    def check(self, fleet, file: str) -> None:
        if not self.positions:
            raise ConfigError(file, "scenario.positions", "at least one position")
        if self.to is not None and self.to not in {r.id for r in fleet.robots}:
            raise ConfigError(file, "scenario.to", "the id of a robot of the fleet", self.to)
