"""Allocation methods by name: the only list of them.

Each entry names ``module:attribute`` of a :class:`runtime.allocation.agent.Method`; the family package
is imported only when asked for.  A new family is one package plus one line here.
"""
from __future__ import annotations

from runtime.allocation.agent import Method
from runtime.lazy import resolve

METHODS: dict[str, str] = {
    "bs": "runtime.allocation.formation.family:BS",              # paper 002 basic market algorithm
    "rtma": "runtime.allocation.formation.family:RTMA",          # paper 002 robot and task mean allocation
    "auction": "runtime.allocation.formation.family:AUCTION",    # epsilon-scaling auction (optimal)
    "coalition": "runtime.allocation.coalition.family:COALITION",  # paper 001 simultaneous coalition auction
    "dr": "runtime.allocation.dr.family:DR",                     # paper 000 Double Round auction
    "comutar": "runtime.allocation.comutar.protocol:COMUTAR",    # paper 003 CoMutaR (several tasks per robot)
}
DEFAULT = "auction"


def names() -> tuple[str, ...]:
    return tuple(METHODS)


def method(name: str) -> Method:
    if name not in METHODS:
        raise KeyError(f"allocation method {name!r}: expected one of {'|'.join(METHODS)}")
    return resolve(METHODS[name])


def options_classes() -> dict[str, type]:
    """``{method: options dataclass}``: the robot config's ``allocation:`` union."""
    return {name: method(name).options for name in METHODS}


def all_methods() -> list[Method]:
    return [method(name) for name in METHODS]
