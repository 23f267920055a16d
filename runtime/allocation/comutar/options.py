"""Options of the CoMutaR method: the schema of a robot config's ``allocation:`` section (``method: comutar``).

Timers follow digest-003 §6: a 1.0 s auction, 0.3 s of query-answer wait per level of the input chain, and
a minimum interval between two task insertions of at least the auction plus 0.5 s, so an auctioneer's
auctions never overlap.  Capacities: the link as the share of the robot's radio given to allocation-managed
data streams (Mb/s), the processor as the share of one core.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from runtime.config.build import rng


@dataclass(frozen=True)
class ComutarOptions:
    method: Literal["comutar"] = "comutar"
    link_capacity: float = field(default=1.0, metadata=rng(0.0, 1000.0))     # Mb/s for data streams between robots
    processor: float = field(default=0.8, metadata=rng(0.0, 64.0))           # cores given to allocated actions
    speed: float = field(default=0.25, metadata=rng(0.01, 2.0))              # m/s: the c-space window's top speed
    turn_rate: float = field(default=2.0, metadata=rng(0.1, 10.0))           # rad/s: the window's top turn rate
    auction_timeout: float = field(default=1.0, metadata=rng(0.05, 60.0))    # s the auctioneer takes bids
    query_wait: float = field(default=0.3, metadata=rng(0.01, 10.0))         # s per level of the input chain
    max_depth: int = field(default=4, metadata=rng(1, 8))                    # actions in one input chain
    insert_interval: float = field(default=1.5, metadata=rng(0.0, 600.0))   # s between two auctions (Delta t)
    award_grace: float = field(default=1.0, metadata=rng(0.0, 60.0))        # s a pre-allocation outlives its auction
    ack_timeout: float = field(default=2.0, metadata=rng(0.05, 60.0))        # s for every member to acknowledge
    resend: float = field(default=0.3, metadata=rng(0.01, 10.0))             # s between award re-sends
    report_period: float = field(default=1.0, metadata=rng(0.05, 60.0))      # s between a holder's reports
    member_timeout: float = field(default=5.0, metadata=rng(0.1, 600.0))     # s of silence before a holder is gone
    max_announces: int = field(default=6, metadata=rng(1, 1000))             # dry rounds in a row: "unservable"
    retry: float = field(default=2.0, metadata=rng(0.0, 600.0))             # s before a task is announced again
    # s: the longest back-off (before the 1-2 x jitter) after awards of a task went unacknowledged in a row
    max_backoff: float = field(default=8.0, metadata=rng(0.0, 600.0))
    status_period: float = field(default=1.0, metadata=rng(0.05, 60.0))      # s between survey status broadcasts
    region_period: float = field(default=0.5, metadata=rng(0.05, 60.0))     # s between region updates to providers
    reader_reach: float = field(default=0.0, metadata=rng(0.0, 1000.0))     # m a reader drives to see a region
    # a stream (10 Hz range data, 5 Hz obstacle list) silent this many of its periods is overdue: its consumer stops
    feed_periods: float = field(default=2.5, metadata=rng(1.0, 100.0))
    region_radius: float = field(default=1.0, metadata=rng(0.0, 50.0))      # m: the region a consumer asks to watch
    # m an obstacle heard by another robot's sensor may reach behind its echo (the side the sensor cannot see)
    shadow_depth: float = field(default=0.3, metadata=rng(0.0, 5.0))
    # s of a provider's streamed discs an avoider keeps (a disc one echo frame misses is still there)
    feed_memory: float = field(default=0.5, metadata=rng(0.0, 60.0))
    max_options: int = field(default=2, metadata=rng(1, 8))                  # providers kept per input
    visit_radius: float = field(default=0.1, metadata=rng(0.01, 5.0))       # m: a waypoint this close is visited
    # m: a survey's claim moves to a free waypoint nearer by more than this (Alg. 2: the nearest at each
    # instant); null: a claim is kept until visited
    switch: float | None = field(default=0.5, metadata=rng(0.0, 100.0))
