"""Options of the dr method: the schema of a robot config's ``allocation:`` section (docs/dr.md lists each).

Timers are seconds: the digest's choices in paper time units converted at 1 tu = 0.12 s (runtime/allocation/dr/
model.py).  ``model`` is a path relative to the config file (``source``, filled in by the config builder).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Optional

from runtime.config.build import rng

_T = rng(0.01, 600)


@dataclass(frozen=True)
class DrOptions:
    method: Literal["dr"] = "dr"
    auction: Literal["dr", "sr", "greedy"] = "dr"                # DR: Alg. 2 + 3; SR: Alg. 2 only; Greedy: award all
    strategy: Literal["M_I", "NM_I", "M_NI", "NM_NI"] = "NM_I"   # M: monitoring; I: interference model
    utility: Literal["soft", "hard"] = "soft"                    # eq. 10 | Fig. 1a
    online: bool = False                                         # on-line SVR learning (§4.2.2)
    late: Literal["all", "fastest"] = "all"                      # eq. 8 cannot hold: award every bidder (the
                                                                 # paper) | only those that bring fT forward
    carrier_leads: bool = False                                  # a robot carrying a load of a leaderless task
                                                                 # may ask to lead it (ours; §5.5.2: free robots)
    speed_belief: Optional[float] = field(default=None, metadata=rng(0.001, 10))   # m/s in eq. 5; null: cruise
    load_capacity: float = field(default=2.0, metadata=rng(0.0, 1e6, lo_open=True))   # wu per trip
    load_time: float = field(default=0.12, metadata=rng(0.0, 3600))     # s per wu to load, and again to unload
    delivery: tuple[float, float] = (0.0, 0.0)                   # m, the delivery point in the fleet frame
    reach: float = field(default=0.3, metadata=rng(0.01, 10))    # m: loads this close to the object
    delivery_reach: Optional[float] = field(default=None, metadata=rng(0.01, 10))   # m: unloads this close to the
                                                                 # delivery point, a delivery area of this radius:
                                                                 # distances (eq. 5, the model) are to its edge;
                                                                 # null: a point, unloaded within reach
    model: Optional[str] = None                                  # interference model file (JSON); null: none yet
    time_leadership: float = field(default=1.2, metadata=_T)     # Alg. 1: s a candidate waits before it leads
    time_auction: float = field(default=1.2, metadata=_T)        # Alg. 2: s the leader collects bids
    time_bid_accepted: float = field(default=0.6, metadata=_T)   # Alg. 3: s a robot collects awards
    award_wait: float = field(default=1.2, metadata=_T)          # s the leader waits for ROBOT_ALIVE
    leader_alive_period: float = field(default=1.2, metadata=_T)     # s between LEADER_ALIVE
    leader_timeout: float = field(default=4.8, metadata=_T)      # s of a silent leader before its members leave
    member_alive_period: float = field(default=1.2, metadata=_T)     # s between a member's ROBOT_ALIVE
    member_timeout: float = field(default=4.8, metadata=_T)      # s of a silent member before its leader drops it
    report_resend: float = field(default=0.5, metadata=_T)       # s between resends of a load/delivery report
    sample_period: float = field(default=10.0, metadata=_T)      # s between repeats of a robot's last SVR sample
    source: str = ""                                             # the config file (set by the builder)

    @property
    def area(self) -> float:
        """The delivery area's radius: how much shorter than to D's centre the way to deliver is (0: a point)."""
        return 0.0 if self.delivery_reach is None else self.delivery_reach

    @property
    def monitoring(self) -> bool:
        return self.strategy.startswith("M_")

    @property
    def interference(self) -> bool:
        return self.strategy.endswith("_I")

    def model_path(self) -> Path | None:
        """``model`` relative to the config file."""
        if self.model is None:
            return None
        path = Path(self.model)
        return path if path.is_absolute() or not self.source else Path(self.source).parent / path
