"""Paper 000's foraging scenario in the world's units (metres, seconds, weight units): where robots start and
objects appear, the seeded draws of an object's weight, deadline and maximum utility, and the utility of a
finished object (eq. 10 and the hard deadline).

Scale (digest-000 section 8): 1 du = 1 cm, 1 tu = 0.12 s, so the paper's 3 du/tu is 0.25 m/s, a deadline of
900 tu is 108 s and loading 1 tu per wu is 0.12 s per wu.  The arena is 10 x 10 m with the delivery point D at
its centre; objects appear uniformly at least 1 m from D (and, so that a robot can stand on them, at least
``wall_margin`` from the walls).
"""
from __future__ import annotations

from collections.abc import Sequence

import math
from dataclasses import dataclass

import numpy as np

from runtime.allocation.dr import model as dr_model
from runtime.errors import InputError

TU = 0.12                 # s per paper time unit
DU = 0.01                 # m per paper distance unit
SOFT_TAIL = 0.07          # eq. 10: the utility halves 0.07 DL after the deadline
DELIVERY_AREA = 1.0       # m: robots unload within this of D (docs/foraging.md: one 0.3 m point jammed the fleet)
MIN_DISTANCE = 2.0        # m: objects appear this far from D's centre at the least (beyond the area and its turns)
MIN_ANGLE = 90.0          # deg: ... and this far apart seen from D (their circuits' turns at the area do not overlap)


@dataclass(frozen=True)
class Dist:
    """A seeded draw: ``const`` (lo), ``uniform`` real in [lo, hi), or ``integers`` in [lo, hi] inclusive."""
    kind: str = "const"
    lo: float = 0.0
    hi: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in ("const", "uniform", "integers"):
            raise InputError(f"distribution kind {self.kind!r}: expected const|uniform|integers")
        if not (math.isfinite(self.lo) and math.isfinite(self.hi)) or (self.kind != "const" and self.hi < self.lo):
            raise InputError(f"{self.kind} distribution [{self.lo}, {self.hi}]: expected finite lo <= hi")

    @classmethod
    def const(cls, value: float) -> "Dist":
        return cls("const", float(value), float(value))

    @classmethod
    def uniform(cls, lo: float, hi: float) -> "Dist":
        return cls("uniform", float(lo), float(hi))

    @classmethod
    def integers(cls, lo: int, hi: int) -> "Dist":
        return cls("integers", float(lo), float(hi))

    def draw(self, rng: np.random.Generator) -> float:
        if self.kind == "const":
            return self.lo
        if self.kind == "uniform":
            return float(rng.uniform(self.lo, self.hi))
        return float(rng.integers(int(self.lo), int(self.hi), endpoint=True))

    @property
    def mean(self) -> float:
        return (self.lo + self.hi) / 2


def utility_soft(elapsed: float, deadline: float, u_max: float) -> float:
    """Eq. 10: ``u_max`` before the deadline, then ``u_max * 0.07 DL / ((fT - DL) + 0.07 DL)``."""
    if elapsed < deadline:
        return u_max
    tail = SOFT_TAIL * deadline
    return u_max * tail / ((elapsed - deadline) + tail)


def utility_hard(elapsed: float, deadline: float, u_max: float) -> float:
    """Fig. 1a: ``u_max`` before the deadline, 0 after."""
    return u_max if elapsed < deadline else 0.0


def work_capacity(distance: float, load: float, speed: float, load_time: float) -> float:
    """Eq. 5 (wu/s): one robot's ideal rate, ``L v / (2 (tau L v + d))``: round trips of ``2 d / v`` plus
    ``tau L`` to load and again to unload (acceleration, turning and the first approach left out).  The agents'
    own eq. 5 (:func:`runtime.allocation.dr.model.work_capacity`), in the scenario's argument order."""
    return dr_model.work_capacity(load, speed, distance, load_time)


def object_place(rng: np.random.Generator, size: float, delivery: tuple[float, float], min_distance: float,
                 wall_margin: float, others: Sequence[tuple[float, float]] = (),
                 min_angle: float = 0.0) -> tuple[float, float]:
    """A point uniform in the arena, at least ``min_distance`` from ``delivery`` and ``wall_margin`` from the
    walls, and seen from ``delivery`` at least ``min_angle`` degrees away from each of ``others`` (the objects
    present: their transports' ways to the delivery point do not run along each other).  Should no point meet the
    angle in 10,000 draws, the draw that misses it least is taken."""
    half = size / 2 - wall_margin
    if half <= 0:
        raise InputError(f"wall_margin {wall_margin}: expected less than half the arena ({size / 2:g} m)")
    bearings = [math.atan2(oy - delivery[1], ox - delivery[0]) for ox, oy in others]
    best, best_gap = None, -1.0
    for _ in range(10000):
        x, y = rng.uniform(-half, half, size=2)
        if math.hypot(x - delivery[0], y - delivery[1]) < min_distance:
            continue
        b = math.atan2(y - delivery[1], x - delivery[0])
        gap = min((abs(math.remainder(b - o, math.tau)) for o in bearings), default=math.pi)
        if math.degrees(gap) >= min_angle:
            return float(x), float(y)
        if gap > best_gap:
            best, best_gap = (float(x), float(y)), gap
    if best is not None:
        return best
    raise InputError(f"min_distance {min_distance} m: no point of the arena is that far from the delivery point")


def starts(rng: np.random.Generator, ids, size: float, radius: float, gap: float = 0.1,
           around: tuple[float, float] = (0.0, 0.0), spread: float | None = None) -> dict[int, tuple[float, float, float]]:
    """Non-overlapping start poses (``gap`` m between bodies, random headings), uniform in the square of side
    ``spread`` about ``around`` (default: the whole arena less a robot radius and the gap from the walls)."""
    half = size / 2 - radius - gap
    side = half if spread is None else min(spread / 2, half)
    out: dict[int, tuple[float, float, float]] = {}
    for rid in ids:
        for _ in range(10000):
            x, y = rng.uniform(-side, side, size=2) + np.asarray(around)
            if abs(x) <= half and abs(y) <= half and all(
                    math.hypot(x - a, y - b) >= 2 * radius + gap for a, b, _ in out.values()):
                out[int(rid)] = (float(x), float(y), float(rng.uniform(-math.pi, math.pi)))
                break
        else:
            raise InputError(f"robot {rid}: no room to start {len(out) + 1} robots {2 * radius + gap:g} m apart "
                             f"in a {2 * side:g} m square")
    return out
