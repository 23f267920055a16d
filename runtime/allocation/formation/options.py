"""Options of the formation methods: the schema of a robot config's ``allocation:`` section."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from runtime.config.build import rng


@dataclass(frozen=True)
class _Rounds:
    bid_timeout: float = field(default=1.0, metadata=rng(0.01, 60))     # s before an auction is asked again
    start_wait: float = field(default=2.0, metadata=rng(0.0, 600))      # s a lower-id free robot gets to start a round
    linger: float = field(default=2.0, metadata=rng(0.0, 600))          # s a robot with no task stays in a quiet round


@dataclass(frozen=True)
class BSOptions(_Rounds):
    method: Literal["bs"] = "bs"
    max_retries: int = field(default=10, metadata=rng(1, 1000))        # re-announcements before an auction closes


@dataclass(frozen=True)
class RTMAOptions(_Rounds):
    method: Literal["rtma"] = "rtma"
    max_retries: int = field(default=10, metadata=rng(1, 1000))


@dataclass(frozen=True)
class AuctionOptions(_Rounds):
    method: Literal["auction"] = "auction"
    cost_unit: float = field(default=0.01, metadata=rng(1e-9, 1e6))    # m: costs are exact to this (eps = unit/(n+1))
    theta: float = field(default=8.0, metadata=rng(1.5, 1000))         # eps-scaling factor per rung
