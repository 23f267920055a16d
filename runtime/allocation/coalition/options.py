"""Options of the coalition method: the schema of a robot config's ``allocation:`` section."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from runtime.config.build import rng


@dataclass(frozen=True)
class CoalitionOptions:
    method: Literal["coalition"] = "coalition"
    bid_window: float = field(default=1.0, metadata=rng(0.01, 60))       # s the auctioneer takes bids after offering
    ack_timeout: float = field(default=2.0, metadata=rng(0.01, 60))      # s every member has to accept an award
    max_candidates: int = field(default=3, metadata=rng(1, 50))          # coalitions a leader proposes per task
    report_period: float = field(default=1.0, metadata=rng(0.05, 60))    # s between a member's reports
    member_timeout: float = field(default=10.0, metadata=rng(0.1, 600))   # s of silence before a coalition is released
    start_wait: float = field(default=2.0, metadata=rng(0.0, 600))       # s before a (new) auctioneer offers tasks
    spacing: float = field(default=0.1, metadata=rng(0.0, 5.0))          # m between neighbours on the meeting ring
    wdp: Literal["auto", "idastar", "bfs", "dp", "sparse", "milp"] = "auto"   # winner determination solver
