"""On-line interference learning (paper 000 §4.2.2, §5.3): samples made by leaders, shared with every robot.

The leader that completes a task makes a sample (mean group size, distance, I) and adds it to its model
(:class:`~runtime.allocation.dr.interference.InterferenceModel`); it broadcasts it as ``DrSvrSample`` numbered
1, 2, ... per origin.  A robot that sees a number skip asks the origin for the missing ones
(``DrSampleRequest``, each at most once per ``sample_period``); the origin repeats its latest sample every
``sample_period`` so that a lost last sample is noticed too.  Each robot adds every sample once, in the order
they reach it.  With ``online`` off nothing is sent and samples heard are not learnt.
"""
from __future__ import annotations

import math
from collections import OrderedDict

from runtime.allocation.dr.messages import DrSampleRequest, DrSvrSample
from runtime.messages import BROADCAST

KEEP = 120                 # own samples kept for resending (the model's window)


class Learning:
    def __init__(self, robot_id: int, model, options, log):
        self.robot_id = robot_id
        self.model = model
        self.o = options
        self.log = log
        self.own: OrderedDict[int, DrSvrSample] = OrderedDict()
        self.seen: dict[int, set[int]] = {}              # origin -> sample numbers learnt
        self.asked: dict[tuple[int, int], float] = {}    # (origin, seq) -> when asked
        self.repeated = -math.inf
        self.learnt = 0

    def originate(self, n: float, d: float, interference: float, now: float) -> list:
        if not self.o.online:
            return []
        seq = (next(reversed(self.own)) if self.own else 0) + 1
        m = DrSvrSample(self.robot_id, BROADCAST, seq, float(n), float(d), float(interference))
        self.own[seq] = m
        while len(self.own) > KEEP:
            self.own.popitem(last=False)
        self._learn(m)
        self.repeated = now
        self.log.info("svr sample %d: n %.2f d %.2f m I %.4f wu/s (%d samples)", seq, n, d, interference,
                      len(self.model.samples))
        return [m]

    def _learn(self, m: DrSvrSample) -> None:
        self.seen.setdefault(m.sender, set()).add(m.seq)
        self.model.add(m.n, m.d, m.interference)
        self.learnt += 1

    def on_sample(self, m: DrSvrSample, now: float) -> list:
        if not self.o.online or m.sender == self.robot_id:
            return []
        seen = self.seen.setdefault(m.sender, set())
        if m.seq not in seen:
            self._learn(m)
        out = []
        for seq in range(max(1, m.seq - KEEP + 1), m.seq):
            if seq not in seen and now - self.asked.get((m.sender, seq), -math.inf) >= self.o.sample_period:
                self.asked[(m.sender, seq)] = now
                out.append(DrSampleRequest(self.robot_id, m.sender, seq))
        return out

    def on_request(self, m: DrSampleRequest) -> list:
        s = self.own.get(m.seq)
        return [] if s is None else [DrSvrSample(self.robot_id, m.sender, s.seq, s.n, s.d, s.interference)]

    def tick(self, now: float) -> list:
        if not self.own or now - self.repeated < self.o.sample_period:
            return []
        self.repeated = now
        return [self.own[next(reversed(self.own))]]
