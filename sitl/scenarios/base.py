"""What every scenario shares: a timetable of hand-overs to the fleet, and a view of the run to judge by."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from runtime.comms.mission import MissionItem

SAME_POSITION = 1e-3        # m: a table entry this close to a handed-in item (same origin and command) is it


@dataclass
class Handover:
    """Items an operator hands to robot ``to`` at ``at`` seconds (one mission upload)."""
    at: float
    to: int
    items: list[MissionItem]
    labels: list[str]
    task_ids: list[int | None] = field(default_factory=list)     # fleet ids, once the table shows them
    done: bool = False                                           # the upload finished (accepted or not)
    result: int | None = None
    error: str | None = None


def match_tasks(h: Handover, table: dict, taken: set[int]) -> None:
    """Find the fleet ids the robot gave ``h``'s items: entries it minted with the same command and position
    (lowest ids first), not already matched to another hand-over."""
    ids = []
    for it in h.items:
        found = None
        for tid in sorted(table):
            r = table[tid]
            if (tid in taken or tid >> 16 != h.to or r.command != it.command
                    or math.hypot(r.x - it.x, r.y - it.y) > SAME_POSITION):
                continue
            found = tid
            break
        if found is not None:
            taken.add(found)
        ids.append(found)
    h.task_ids = ids
