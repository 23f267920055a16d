"""DAMN-style command arbitration (Rosenblatt 1997; paper 002 Section III and IV-C).

Behaviours vote over a fixed set of (speed, turn-rate) arcs with votes in [-1, 1] and may veto arcs.  The
arbiter sums the weighted votes, smooths the sum with a Gaussian over neighbouring arcs (DAMN's vote
smoothing, so a narrow peak next to a strongly disliked arc loses to a broad good region), drops vetoed
arcs and commands the best one.  Sans-IO: sensor input and decisions all take ``now`` (seconds).

The behaviours the executive runs (following a path, avoiding obstacles, stopping) are in
:mod:`runtime.control.behaviours`; CoMutaR's c-space constraints vote through
:mod:`runtime.control.cspace`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property, lru_cache
from typing import Protocol

import numpy as np

from runtime.control import compiled
from runtime.errors import InputError


@dataclass(frozen=True)
class ArcSet:
    """The candidate commands: every (speed, turn rate) pair of two sorted axes; arc k = (k // nw, k % nw)."""
    speeds: tuple[float, ...]
    turn_rates: tuple[float, ...]

    def __post_init__(self) -> None:
        for name in ("speeds", "turn_rates"):
            axis = getattr(self, name)
            if len(axis) < 1 or any(not math.isfinite(a) for a in axis) or list(axis) != sorted(set(axis)):
                raise InputError(f"arc set {name}: expected strictly increasing finite values, got {axis!r}")
        if 0.0 not in self.speeds:
            raise InputError(f"arc set speeds: expected 0.0 among them (to stop), got {self.speeds!r}")
        object.__setattr__(self, "_hash", hash((self.speeds, self.turn_rates)))

    def __hash__(self) -> int:
        """The fields' hash, computed once: the behaviours' caches look an arc set up several times a cycle."""
        return self._hash

    def __eq__(self, other) -> bool:
        """Equal axes; the same object at once (every robot with the same tunables shares one: :meth:`uniform`)."""
        if self is other:
            return True
        if not isinstance(other, ArcSet):
            return NotImplemented
        return self._hash == other._hash and self.speeds == other.speeds and self.turn_rates == other.turn_rates

    @classmethod
    def uniform(cls, max_speed: float = 0.5, max_reverse: float = 0.2, max_turn_rate: float = 2.0,
                n_speeds: int = 11, n_turns: int = 21) -> "ArcSet":
        """Evenly spaced forward speeds in [0, max_speed], plus reverse speeds down to -max_reverse at the same
        spacing, and turn rates in [-max_turn_rate, max_turn_rate] (defaults fit an iRobot Create 2).  One object
        per set of arguments: an arc set is immutable, and the behaviours' caches keyed by it then find their
        entries by identity instead of comparing its axes (several times a cycle per robot)."""
        return cls._uniform(float(max_speed), float(max_reverse), float(max_turn_rate), int(n_speeds), int(n_turns))

    @classmethod
    @lru_cache(maxsize=64)
    def _uniform(cls, max_speed: float, max_reverse: float, max_turn_rate: float, n_speeds: int,
                 n_turns: int) -> "ArcSet":
        fwd = np.linspace(0.0, max_speed, n_speeds)
        dv = fwd[1] - fwd[0] if n_speeds > 1 else max_speed
        rev = -np.arange(dv, max_reverse + 1e-9, dv)[::-1] if max_reverse > 0 and dv > 0 else np.zeros(0)
        turns = np.linspace(-max_turn_rate, max_turn_rate, n_turns)
        return cls(tuple(float(v) for v in np.concatenate((rev, fwd))), tuple(float(w) for w in turns))

    @property
    def shape(self) -> tuple[int, int]:
        return len(self.speeds), len(self.turn_rates)

    @cached_property
    def v(self) -> np.ndarray:
        """Speed of every arc (flat, length n_speeds * n_turns; read-only, computed once)."""
        return _frozen(np.repeat(np.asarray(self.speeds), len(self.turn_rates)))

    @cached_property
    def w(self) -> np.ndarray:
        """Turn rate of every arc (flat; read-only, computed once)."""
        return _frozen(np.tile(np.asarray(self.turn_rates), len(self.speeds)))

    def nearest(self, v: float, w: float) -> int:
        """Index of the arc closest to (v, w), each axis measured in its own spacing."""
        v, w = float(v), float(w)        # Python floats: the same first closest index as np.argmin, no numpy calls
        iv = _first_closest(self.speeds, v)
        iw = _first_closest(self.turn_rates, w)
        return iv * len(self.turn_rates) + iw


def _first_closest(axis: tuple[float, ...], x: float) -> int:
    """``int(np.argmin(np.abs(np.asarray(axis) - x)))``: the first index of the least distance (0 when ``x`` is
    NaN, as argmin of all-NaN is)."""
    best, at = math.inf, 0
    for i, a in enumerate(axis):
        d = abs(a - x)
        if d < best:
            best, at = d, i
    return at


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def smoothing_matrix(n: int, sigma: float, truncate: float = 4.0) -> np.ndarray:
    """The n x n matrix that applies scipy.ndimage.gaussian_filter1d(x, sigma, mode="nearest") to a length-n
    axis: the same kernel (radius int(truncate * sigma + 0.5), normalised), edges repeated.  The arbiter
    smooths every cycle, so it multiplies by two of these instead of calling the filter."""
    radius = int(truncate * float(sigma) + 0.5)
    k = np.exp(-0.5 * (np.arange(-radius, radius + 1) / float(sigma)) ** 2)
    k /= k.sum()
    m = np.zeros((n, n))
    for i in range(n):
        for off, weight in zip(range(-radius, radius + 1), k):
            m[i, min(max(i + off, 0), n - 1)] += weight
    return m


@dataclass
class Ballot:
    """One behaviour's opinion: votes in [-1, 1] per arc, and arcs it forbids."""
    votes: np.ndarray
    veto: np.ndarray | None = None


class Behaviour(Protocol):
    name: str
    weight: float

    def ballot(self, arcs: ArcSet, now: float) -> Ballot: ...


def _clip1(votes: np.ndarray) -> np.ndarray:
    """``np.clip(votes, -1, 1)`` without its Python-level dispatch (the arbiter clips every ballot every cycle)."""
    return np.minimum(np.maximum(votes, -1.0), 1.0)


@dataclass
class Decision:
    v: float
    w: float
    arc: int
    scores: np.ndarray          # smoothed weighted sum per arc, -inf where vetoed


@dataclass
class Arbiter:
    """Sums weighted behaviour votes, Gaussian-smooths them over neighbouring arcs, picks the best arc."""
    arcs: ArcSet
    behaviours: list
    smoothing: float = 1.0       # Gaussian sigma in arcs along each axis (0: none)
    vetoed_all: int = 0          # decisions where every arc was vetoed (the arbiter then stands still)

    def __post_init__(self) -> None:
        self._smoothers: tuple = (None, None, None)     # (sigma, along speeds, along turn rates)
        for b in self.behaviours:
            if not (isinstance(b.weight, (int, float)) and math.isfinite(b.weight) and b.weight >= 0):
                raise InputError(f"arbiter behaviour {b.name} weight: expected a finite number >= 0, got {b.weight!r}")

    def decide(self, now: float) -> Decision:
        arcs, fast = self.arcs, compiled.ENABLED
        ballots = [(b.ballot(arcs, now), b) for b in self.behaviours]
        total = np.zeros(len(arcs.v))
        veto = np.zeros(len(arcs.v), dtype=bool)
        nan = False                                     # known to hold no NaN while every ballot went compiled
        for ballot, b in ballots:
            if fast and ballot.votes.dtype == np.float64:
                nan = compiled.weighted_sum(total, ballot.votes, float(b.weight))
            else:
                total += b.weight * _clip1(ballot.votes)  # clipping maps +-inf to +-1, as nan_to_num then clip does
                nan = None
            if ballot.veto is not None:
                veto |= ballot.veto
        if nan or (nan is None and np.isnan(total).any()):   # a NaN vote (or weight): sum again, NaN votes as 0
            total[:] = 0.0
            for ballot, b in ballots:
                total += b.weight * _clip1(np.nan_to_num(ballot.votes, nan=0.0))
        grid = total.reshape(arcs.shape)
        if self.smoothing > 0:
            if self._smoothers[0] != self.smoothing:
                nv, nw = arcs.shape
                self._smoothers = (self.smoothing, smoothing_matrix(nv, self.smoothing),
                                   smoothing_matrix(nw, self.smoothing))
            grid = self._smoothers[1] @ grid @ self._smoothers[2].T
        if fast:
            scores, k = compiled.best_arc(grid.ravel(), veto)
            if k < 0:
                self.vetoed_all += 1
                return Decision(0.0, 0.0, arcs.nearest(0.0, 0.0), scores)
            return Decision(float(arcs.v[k]), float(arcs.w[k]), k, scores)
        scores = np.where(veto, -np.inf, grid.ravel())
        if veto.all():
            self.vetoed_all += 1
            stop = arcs.nearest(0.0, 0.0)
            return Decision(0.0, 0.0, stop, scores)
        k = int(scores.argmax())
        return Decision(float(arcs.v[k]), float(arcs.w[k]), k, scores)
