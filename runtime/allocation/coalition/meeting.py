"""Where the members of a coalition stand when they meet: evenly spaced on a ring around the task's point.

Robots have bodies: k of them cannot all stand on one point.  Member i of k (its position in the award's
``robots``) goes to the point plus ``ring_radius`` in the direction ``2 pi i / k`` (east first, counter-
clockwise); the ring is just wide enough for neighbours to keep ``spacing`` between their footprints.  A
coalition of one meets on the point itself.  The auctioneer lists the members in the order of their
bearings from the point, rotated to fit the slots best, so nobody crosses the ring to reach its slot.
"""
from __future__ import annotations

import itertools
import math
from typing import Mapping, Sequence


def ring_radius(k: int, radius: float, spacing: float) -> float:
    """m from the point to each member's slot: neighbours' centres 2 * radius + spacing apart."""
    if k <= 1:
        return 0.0
    return (radius + spacing / 2.0) / math.sin(math.pi / k)


def slot(point: tuple[float, float], k: int, index: int, radius: float, spacing: float) -> tuple[float, float]:
    """The meeting spot of member ``index`` (0-based) of ``k``."""
    r = ring_radius(k, radius, spacing)
    a = 2.0 * math.pi * index / max(k, 1)
    return point[0] + r * math.cos(a), point[1] + r * math.sin(a)


def _gap(a: float, b: float) -> float:
    d = (a - b) % (2.0 * math.pi)
    return min(d, 2.0 * math.pi - d)


def ring_order(point: tuple[float, float], robots: Sequence[int],
               positions: Mapping[int, tuple[float, float]]) -> tuple[int, ...]:
    """``robots`` in slot order: sorted by bearing from ``point`` and rotated so that the members' bearings
    are closest to their slots' directions.  Robots whose position is unknown keep the sorted order's tail."""
    known = [r for r in sorted(robots) if r in positions]
    unknown = [r for r in sorted(robots) if r not in positions]
    k = len(robots)
    if k <= 1 or not known:
        return tuple(sorted(robots))
    bearing = {r: math.atan2(positions[r][1] - point[1], positions[r][0] - point[0]) for r in known}
    ring = sorted(known, key=lambda r: (bearing[r] % (2.0 * math.pi), r))
    best, best_cost = None, math.inf
    for shift in range(len(ring)):
        order = ring[shift:] + ring[:shift]
        cost = sum(_gap(bearing[r], 2.0 * math.pi * i / k) for i, r in enumerate(order))
        if cost < best_cost - 1e-12:
            best, best_cost = order, cost
    return tuple(itertools.chain(best, unknown))
