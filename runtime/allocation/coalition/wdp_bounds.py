"""Exact bid pruning by bounds, before the exact solvers run.

A greedy allocation gives a lower bound LB on the optimum.  For a bid b, no allocation that
contains it is worth more than v_b + h(robots outside b), with h the paper's robot-share bound
(each robot counted at its best value/size over all bids).  Bids with that bound below LB are in
no optimal allocation and are dropped; every optimal allocation survives, so the optimum is
unchanged.  Two rounds: the first cut lowers h for the second.
"""
from __future__ import annotations

import math

import numpy as np

from runtime.allocation.coalition.wdp_model import Compiled


def greedy(c: Compiled, order: np.ndarray, full: int, n_tasks: int) -> float:
    """Total of the allocation taking bids in ``order`` whenever robots and task are free
    (stops once all ``full`` robots or all ``n_tasks`` bid-on tasks are taken)."""
    used, tasks, total = 0, set(), 0.0
    for i in order.tolist():
        m, t = c.mask[i], c.task[i]
        if m & used or t in tasks:
            continue
        used |= m
        tasks.add(t)
        total += c.value[i]
        if used == full or len(tasks) == n_tasks:
            break
    return total


def upper_bound(c: Compiled) -> float:
    """No allocation is worth more: the smaller of the sum over tasks of their best bid and the sum over robots
    of their best value per coalition member."""
    per_task: dict[int, float] = {}
    per_robot: dict[int, float] = {}
    for t, m, v in zip(c.task, c.mask, c.value):
        per_task[t] = max(per_task.get(t, 0.0), v)
        share = v / max(m.bit_count(), 1)
        while m:
            low = m & -m
            r = low.bit_length() - 1
            per_robot[r] = max(per_robot.get(r, 0.0), share)
            m ^= low
    return min(math.fsum(per_task.values()), math.fsum(per_robot.values()))


def prune(c: Compiled, rounds: int = 2) -> Compiled:
    """``c`` without bids that cannot be in an optimal allocation (robot masks up to 62 bits)."""
    if c.n_bids < 2 or c.n_robots > 62:
        return c
    mask = np.asarray(c.mask, dtype=np.int64)
    value = np.asarray(c.value, dtype=np.float64)
    bits = np.arange(c.n_robots, dtype=np.int64)
    member = ((mask[:, None] >> bits[None, :]) & 1).astype(np.float64)      # bids x robots
    size = member.sum(axis=1)
    share = value / size
    full = int(np.bitwise_or.reduce(mask))
    n_tasks = len(set(c.task))
    lb = max(greedy(c, np.argsort(-share, kind="stable"), full, n_tasks),
             greedy(c, np.argsort(-value, kind="stable"), full, n_tasks))
    eps = 1e-9 * max(1.0, lb)
    idx = np.arange(c.n_bids)
    for _ in range(rounds):
        contrib = (member * share[:, None]).max(axis=0)
        bound = value + (contrib.sum() - member @ contrib)
        keep = bound >= lb - eps
        if keep.all():
            break
        idx, member, value, share = idx[keep], member[keep], value[keep], share[keep]
    if len(idx) == c.n_bids:
        return c
    il = idx.tolist()
    return Compiled(c.n_robots, c.n_tasks, tuple(c.task[i] for i in il), tuple(c.mask[i] for i in il),
                    tuple(c.value[i] for i in il), tuple(c.bid_ids[i] for i in il))
