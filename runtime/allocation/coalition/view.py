"""What one robot knows of the fleet, shared by its auctioneer and member roles: the open tasks, the peers'
last ``RobotState`` (state, tasks held, position), who is lost, and so who the auctioneer is.

The auctioneer is the lowest-id live robot: this robot and every configured peer (or one that joined since) heard
and not lost since.
Every robot works it out alone from what it hears; views agree once the states have spread.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from runtime.messages import IDLE, RobotState
from runtime.tasks import Task


@dataclass
class Peer:
    heard: float = -math.inf          # last message of any kind
    state: int | None = None          # last RobotState: None until one is heard
    tasks: tuple[int, ...] = ()
    x: float = math.nan
    y: float = math.nan


class FleetView:
    def __init__(self, robot_id: int, peers):
        self.robot_id = int(robot_id)
        self.configured = frozenset(int(p) for p in peers) - {self.robot_id}
        self.peers: dict[int, Peer] = {}
        self.lost: set[int] = set()
        self.tasks: dict[int, Task] = {}        # open tasks this method allocates, by fleet id

    # ------------------------------------------------------------------ input
    def known(self, rid) -> bool:
        """A configured peer (messages from anyone else are not fleet business)."""
        return isinstance(rid, int) and rid in self.configured

    def heard(self, rid: int, now: float) -> None:
        if not self.known(rid):
            return
        self.lost.discard(rid)
        self.peers.setdefault(rid, Peer()).heard = now

    def on_state(self, m: RobotState) -> bool:
        """Take a peer's state; False (and nothing taken) if its values are not a state's."""
        try:
            ok = m.invalid() is None and all(isinstance(t, int) for t in m.tasks)
            x, y = float(m.x), float(m.y)
        except (TypeError, ValueError):
            return False
        if not ok:
            return False
        p = self.peers.setdefault(m.sender, Peer())
        p.state, p.tasks, p.x, p.y = m.state, tuple(m.tasks), x, y
        return True

    def join(self, rid: int) -> None:
        """A robot that joined the fleet at run time: a peer from now on (live once heard)."""
        if rid != self.robot_id:
            self.configured |= {int(rid)}
            self.lost.discard(rid)

    def on_lost(self, rid: int) -> None:
        if rid in self.configured:
            self.lost.add(rid)

    # ------------------------------------------------------------------ views
    def live(self) -> list[int]:
        return sorted([self.robot_id] + [p for p in self.peers if p not in self.lost])

    def is_live(self, rid: int) -> bool:
        return rid == self.robot_id or (rid in self.peers and rid not in self.lost)

    def auctioneer(self) -> int:
        return min(self.live())

    def position(self, rid: int) -> tuple[float, float] | None:
        p = self.peers.get(rid)
        if p is None or not (math.isfinite(p.x) and math.isfinite(p.y)):
            return None
        return p.x, p.y

    def idle(self, rid: int) -> bool:
        """A live peer whose last state says it is idle and holds nothing."""
        p = self.peers.get(rid)
        return p is not None and rid not in self.lost and p.state == IDLE and not p.tasks

    def held(self) -> set[int]:
        """Tasks live peers say they hold."""
        return {t for rid, p in self.peers.items() if rid not in self.lost for t in p.tasks}
