"""Share-restricted resources and the admission test of paper 003 (CoMutaR), eqs. 1-5.

A :class:`Resource` is owned by a robot (``owner`` > 0) or by the environment (``owner`` 0) and has a
codomain with two operators (an :class:`Algebra`):

* the compound operator (eq. 1) joins two demands: ``+`` for bandwidth and processor, set intersection
  for the allowed configuration space;
* the comparison operator (eq. 2) says whether a joined demand fits the capacity: ``<=`` for the scalars,
  "non-empty" for the c-space (whose capacity is unused: the digest's rho_max = empty set).

A non-running action is the identity of the compound operator (0 for the scalars, the whole space for the
c-space), so it is simply absent from the :class:`Ledger`.  A demand (the value of a constraint function
phi(t)) is a value of the codomain or a callable ``phi(now)`` returning one; c-space values are boolean numpy
masks over one robot's candidate next-frame configurations (:mod:`~runtime.control.cspace`), or
None for "forbids nothing".

The :class:`Ledger` holds what every running (allocated) and pre-allocated action demands of each resource
it knows, and admits a new demand only if, for every resource it names, the compound of all holds with the
new demand still fits (eq. 5 over every robot's actions).  Pre-allocations carry an expiry time and vanish
on :meth:`Ledger.expire`; allocations stay until released.  Every hold counts against every other (the
admission test of Alg. 1 as printed) unless the caller names rivals to leave out (``exclude``): CoMutaR's
bidder leaves out the other candidates of the same auction (digest §7), which cannot all win; so the
allocations never exceed a capacity, and neither do the pre-allocations of any one auction beside them.
"""
from __future__ import annotations

import math
import operator
from dataclasses import dataclass, field
from typing import Any, Callable, Hashable, Mapping

import numpy as np

from runtime.errors import InputError

SCALAR, CSPACE = "scalar", "cspace"
EPS = 1e-9                       # slack of the scalar comparison (sums of floats)


@dataclass(frozen=True)
class Algebra:
    """The two operators of a codomain and the compound operator's identity (a non-running action)."""
    name: str
    identity: Any
    compound: Callable[[Any, Any], Any]          # eq. 1
    fits: Callable[[Any, Any], bool]             # eq. 2: (joined demand, capacity) -> within capacity


def _intersect(a, b):
    if a is None:
        return b
    if b is None:
        return a
    return np.logical_and(a, b)


def _non_empty(total, capacity) -> bool:
    return total is None or bool(np.any(total))


ALGEBRAS = {
    SCALAR: Algebra(SCALAR, 0.0, operator.add, lambda total, cap: total <= cap + EPS),
    CSPACE: Algebra(CSPACE, None, _intersect, _non_empty),
}


@dataclass(frozen=True)
class Resource:
    """rho^{k,l}: resource ``name`` of ``owner`` (a robot id, or 0 for the environment)."""
    owner: int
    name: str
    kind: str = SCALAR
    capacity: float | None = None                 # rho_max (scalar); unused for the c-space
    unit: str = ""

    def __post_init__(self) -> None:
        if not (isinstance(self.owner, int) and 0 <= self.owner <= 250):
            raise InputError(f"resource {self.name}: owner: expected 0 (environment) or a robot id 1..250, got {self.owner!r}")
        if self.kind not in ALGEBRAS:
            raise InputError(f"resource {self.name}: kind: expected {'|'.join(ALGEBRAS)}, got {self.kind!r}")
        if self.kind == SCALAR and not (isinstance(self.capacity, (int, float)) and math.isfinite(self.capacity)
                                        and self.capacity >= 0):
            raise InputError(f"resource {self.name} of {self.owner}: capacity: expected a finite number >= 0, "
                             f"got {self.capacity!r}")

    @property
    def key(self) -> tuple[int, str]:
        return self.owner, self.name

    @property
    def algebra(self) -> Algebra:
        return ALGEBRAS[self.kind]


Key = tuple[int, str]
Demand = Any                        # a codomain value, or a callable now -> value


def evaluate(demand: Demand, now: float):
    """phi(now): the value of a demand (constant or a function of time)."""
    return demand(now) if callable(demand) else demand


@dataclass
class Hold:
    """What one holder (an action instance) demands of each resource; ``expires`` None once allocated."""
    demands: dict[Key, Demand]
    expires: float | None
    tag: Any = None                 # the holder's business (auction, task) for the caller

    @property
    def allocated(self) -> bool:
        return self.expires is None


@dataclass
class Ledger:
    """The resources a robot accounts for and every hold on them (see the module docstring)."""
    resources: dict[Key, Resource] = field(default_factory=dict)
    holds: dict[Hashable, Hold] = field(default_factory=dict)
    refused: int = 0                # admission tests that failed
    expired: int = 0                # pre-allocations that expired

    def add(self, resource: Resource) -> None:
        self.resources[resource.key] = resource

    # ------------------------------------------------------------------ eqs. 3-5
    def total(self, key: Key, now: float, exclude=()):
        """The compound of every hold's demand on ``key`` (eqs. 3-4): the identity when nothing holds it."""
        alg = self.resources[key].algebra
        out = alg.identity
        for holder, hold in self.holds.items():
            if key in hold.demands and holder not in exclude:
                out = alg.compound(out, evaluate(hold.demands[key], now))
        return out

    def check(self, demands: Mapping[Key, Demand], now: float, exclude=()) -> str | None:
        """Why ``demands`` cannot be admitted beside every hold (eq. 5 per resource), or None if they can."""
        for key, demand in demands.items():
            res = self.resources.get(key)
            if res is None:
                return f"resource {key[1]} of {_owner(key[0])} is not accounted here"
            alg = res.algebra
            joined = alg.compound(evaluate(demand, now), self.total(key, now, exclude))
            if not alg.fits(joined, res.capacity):
                return _refusal(res, joined, evaluate(demand, now))
        return None

    def join(self, demands: list[Mapping[Key, Demand]], now: float) -> dict[Key, Any]:
        """Several holders' demands compounded per resource (eq. 3 over them), evaluated at ``now``."""
        out: dict[Key, Any] = {}
        for d in demands:
            for key, value in d.items():
                v = evaluate(value, now)
                out[key] = self.resources[key].algebra.compound(out[key], v) if key in out else v
        return out

    def fits(self, now: float, allocated_only: bool = False) -> dict[Key, bool]:
        """Per resource: does everything held (or everything allocated) fit?"""
        out = {}
        for k, r in self.resources.items():
            alg, total = r.algebra, r.algebra.identity
            for hold in self.holds.values():
                if k in hold.demands and (hold.allocated or not allocated_only):
                    total = alg.compound(total, evaluate(hold.demands[k], now))
            out[k] = alg.fits(total, r.capacity)
        return out

    # ------------------------------------------------------------------ holds
    def preallocate(self, holder: Hashable, demands: Mapping[Key, Demand], now: float, expires: float,
                    tag: Any = None, exclude=()) -> str | None:
        """Admit and hold ``demands`` until ``expires`` (or until allocated); returns why not, or None.
        A holder that already holds is replaced (its old demands do not count against its new ones), and so
        are the holders in ``exclude`` not counted (rivals the caller knows cannot run beside it)."""
        why = self.check(demands, now, exclude=(holder, *exclude))
        if why is not None:
            self.refused += 1
            return why
        self.holds[holder] = Hold(dict(demands), float(expires), tag)
        return None

    def allocate(self, holder: Hashable, now: float, demands: Mapping[Key, Demand] | None = None,
                 tag: Any = None) -> str | None:
        """Turn a hold into an allocation (no expiry), optionally with new demands; a holder not held (its
        pre-allocation expired) is admitted afresh.  Returns why not (nothing changes then), or None."""
        hold = self.holds.get(holder)
        if demands is None:
            if hold is None:
                return "nothing pre-allocated"
            demands = hold.demands
        why = self.check(demands, now, exclude=(holder,))
        if why is not None:
            self.refused += 1
            return why
        self.holds[holder] = Hold(dict(demands), None, hold.tag if tag is None and hold is not None else tag)
        return None

    def release(self, holder: Hashable) -> bool:
        return self.holds.pop(holder, None) is not None

    def expire(self, now: float) -> list[Hashable]:
        """Drop every pre-allocation whose time is up; returns their holders."""
        gone = [h for h, hold in self.holds.items() if hold.expires is not None and hold.expires <= now]
        for h in gone:
            del self.holds[h]
        self.expired += len(gone)
        return gone

    def preallocated(self) -> dict[Hashable, Hold]:
        return {h: x for h, x in self.holds.items() if not x.allocated}

    def used(self, key: Key, now: float, allocated_only: bool = False) -> float:
        """Scalar resources: the amount held (all holds, or allocations only)."""
        total = 0.0
        for hold in self.holds.values():
            if key in hold.demands and (hold.allocated or not allocated_only):
                total += float(evaluate(hold.demands[key], now))
        return total


def _owner(owner: int) -> str:
    return "the environment" if owner == 0 else f"robot {owner}"


def _refusal(res: Resource, joined, demand) -> str:
    if res.kind == CSPACE:
        return f"{res.name} of {_owner(res.owner)}: no configuration left that every action allows"
    return (f"{res.name} of {_owner(res.owner)}: {float(joined):.4g}{res.unit} would exceed the capacity "
            f"{res.capacity:.4g}{res.unit} (asked {float(demand):.4g})")
