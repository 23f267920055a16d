"""In-memory message bus for sans-IO agents: tests and fast experiment loops.

Delivers each message to its ``dest`` (or to every other agent for dest 0) after a delay, and can
drop, duplicate and reorder under a seeded RNG.  Counts every message sent, so experiments report
communication cost the same way for every method.
"""
from __future__ import annotations

import heapq
import itertools
import random
from dataclasses import dataclass, field
from typing import Any, Iterable, Protocol

from runtime.messages import BROADCAST


class Agent(Protocol):
    robot_id: int

    def on_message(self, msg: Any, now: float) -> list: ...
    def on_tick(self, now: float) -> list: ...


@dataclass
class BusStats:
    sent: int = 0          # messages handed to the bus by agents (a broadcast counts once)
    delivered: int = 0     # copies delivered to agents
    dropped: int = 0
    duplicated: int = 0


@dataclass
class InMemoryBus:
    agents: dict[int, Agent]
    delay: float = 0.01            # mean one-way delay (s)
    jitter: float = 0.0            # uniform +- jitter: with jitter > 0 messages can reorder
    drop: float = 0.0              # probability a copy is lost
    duplicate: float = 0.0         # probability a copy is delivered twice
    seed: int = 0
    down: set[int] = field(default_factory=set)   # robots that neither send nor receive
    stats: BusStats = field(default_factory=BusStats)

    def __post_init__(self) -> None:
        self._rng = random.Random(self.seed)
        self._queue: list[tuple[float, int, int, Any]] = []
        self._seq = itertools.count()
        self.now = 0.0

    def send(self, msgs: Iterable[Any], now: float) -> None:
        for msg in msgs:
            if msg.sender in self.down:
                continue
            self.stats.sent += 1
            targets = [msg.dest] if msg.dest != BROADCAST else [r for r in self.agents if r != msg.sender]
            for dest in targets:
                if dest not in self.agents or self._rng.random() < self.drop:
                    self.stats.dropped += 1
                    continue
                copies = 2 if self._rng.random() < self.duplicate else 1
                self.stats.duplicated += copies - 1
                for _ in range(copies):
                    t = now + max(0.0, self.delay + self._rng.uniform(-self.jitter, self.jitter))
                    heapq.heappush(self._queue, (t, next(self._seq), dest, msg))

    def run(self, until: float, tick: float = 0.05, stop=None) -> float:
        """Advance time to ``until``: deliver due messages in time order, tick every agent each
        ``tick`` seconds.  ``stop()`` returning true ends the run early.  Returns the end time."""
        next_tick = self.now
        while self.now < until:
            if stop is not None and stop():
                break
            t_msg = self._queue[0][0] if self._queue else float("inf")
            if t_msg <= next_tick:
                self._deliver_next()
            else:
                self.now = next_tick
                for rid, agent in self.agents.items():
                    if rid not in self.down:
                        self.send(agent.on_tick(self.now), self.now)
                next_tick += tick
        return self.now

    def deliver(self, until: float) -> None:
        """Deliver every message due by ``until`` (in time order, each at its own time), then move the clock to
        ``until``: for hosts that interleave the bus with their own control cycles."""
        while self._queue and self._queue[0][0] <= until:
            self._deliver_next()
        self.now = max(self.now, until)

    def _deliver_next(self) -> None:
        t, _, dest, msg = heapq.heappop(self._queue)
        self.now = max(self.now, t)
        if dest in self.down:
            self.stats.dropped += 1
            return
        self.stats.delivered += 1
        self.send(self.agents[dest].on_message(msg, self.now), self.now)

    def idle(self) -> bool:
        return not self._queue
