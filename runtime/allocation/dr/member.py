"""The robot's side of the Double Round auction: asking to lead a task (Alg. 1), choosing among leaders' awards
(Alg. 3) and being a member (§5.5.2, §5.5.3).

* **Leadership request** (Alg. 1).  A free robot (no task, no award waiting, armed and localised) asks to lead
  the nearest task with no known leader (none heard within ``leader_timeout``) and no recent request heard
  (:meth:`~runtime.allocation.dr.world.World.claimed`): ``DrLeaderRequest`` with its work capacity.  It gives up
  when, within ``time_leadership``, it hears the task's leader or a better candidate (higher capacity; equal
  capacities: higher id, as §5.5.1 breaks ties); otherwise it leads.
* **Awards** (Alg. 3).  The first ``DrAward`` opens a window of ``time_bid_accepted``; then the robot confirms
  the best (highest value; equal values: the nearest object, then the lower leader id) with ``DrRobotAlive`` and
  refuses the others (``DrRefuse``).  SR and Greedy (``auction: sr | greedy``) take the first award at once.
  A robot waiting on awards still bids.
* **Member.**  ``DrRobotAlive`` every ``member_alive_period``; it leaves a leader silent for ``leader_timeout``
  (no ``DrLeaderAlive``/``DrLedger``), lost, or telling it to (``DrExitLeader``), and once nothing is left at the
  object and it carries nothing.  A robot leaving with a load on board delivers it first (a *carrier*).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

SAME = 1e-6          # relative: capacities and values this close are equal (they travel as float32)


def close(a: float, b: float) -> bool:
    return abs(a - b) <= SAME * max(1.0, abs(a), abs(b))


def better(capacity: float, robot: int, than_capacity: float, than_robot: int) -> bool:
    """Alg. 1's "better": the higher work capacity; equal capacities: the higher id."""
    if close(capacity, than_capacity):
        return robot > than_robot
    return capacity > than_capacity


@dataclass
class Request:
    task: int
    since: float
    capacity: float


@dataclass(frozen=True)
class Offer:
    leader: int
    task: int
    round: int
    value: float
    distance: float           # m from this robot to the task's object


@dataclass
class Offers:
    """Awards collected in Alg. 3's window."""
    by_leader: dict = field(default_factory=dict)
    until: float = math.inf

    def __bool__(self) -> bool:
        return bool(self.by_leader)

    def add(self, offer: Offer, now: float, window: float) -> None:
        if not self.by_leader:
            self.until = now + window
        self.by_leader[offer.leader] = offer

    def ranked(self) -> list[Offer]:
        """Best first: the highest value, then the nearest object, then the lower leader id."""
        best = max((o.value for o in self.by_leader.values()), default=0.0)
        return sorted(self.by_leader.values(),
                      key=lambda o: (0 if close(o.value, best) else 1, -o.value, o.distance, o.leader))

    def clear(self) -> None:
        self.by_leader.clear()
        self.until = math.inf


@dataclass
class Membership:
    task: int
    leader: int
    joined: float
    leader_heard: float
    next_alive: float
    partners: tuple[int, ...] = ()
