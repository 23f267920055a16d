"""Exact winner determination by dynamic programming over robot subsets (few robots, many bids).

``best_t[S]`` = the best total using only tasks 1..t and only robots in S.  One layer per task:
``best_t[S] = max(best_{t-1}[S], max over bids (c, v) of task t with c in S of best_{t-1}[S - c] + v)``.
Small inputs do a layer as one dense gather over (bid, S); larger ones touch only each bid's
2^(n-|c|) supersets (strided table views, or batched index pairs and a scatter-max).  The bids are
reduced first:

* bids with value <= 0 never raise the total and are dropped; for one task and one coalition only
  the best bid is kept;
* a robot that appears in at most one remaining bid can never conflict and leaves the mask;
  robots that appear in exactly the same bids always move together and share one bit.

:func:`solve_sparse` runs the same recursion in plain Python over the robot sets actually reached,
which is faster than numpy for a few dozen bids.
"""
from __future__ import annotations

import numpy as np

from runtime.allocation.coalition.wdp_model import Compiled, SolverOutput, TimeUp, past

MAX_BITS = 20          # 2^20 float64 states per layer = 8 MiB
VIEW_MIN_FREE = 4      # bids leaving >= this many robots free update table views, not pairs
DENSE_MAX = 1 << 18    # bids x states up to which every layer is one dense gather
MAX_STATES = 1_000_000  # robot sets the plain-Python DP holds (~330 bytes each): then it stops as at a time limit


def reduce(c: Compiled) -> tuple[list[int], list[int], list[float], list[int], int]:
    """Reduced bids: (task, compact mask, value, local bid index) lists and the number of bits."""
    if c.n_robots <= 62 and c.n_bids:
        return _reduce_np(c)
    return _reduce_py(c)


def _reduce_np(c: Compiled):
    task = np.asarray(c.task, dtype=np.int64)
    mask = np.asarray(c.mask, dtype=np.int64)
    value = np.asarray(c.value, dtype=np.float64)
    idx = np.flatnonzero(value > 0.0)
    if not len(idx):
        return [], [], [], [], 0
    # best bid per (task, mask): sort by task, mask, value descending, index; keep the first
    order = np.lexsort((idx, -value[idx], mask[idx], task[idx]))
    idx = idx[order]
    first = np.ones(len(idx), dtype=bool)
    first[1:] = (task[idx[1:]] != task[idx[:-1]]) | (mask[idx[1:]] != mask[idx[:-1]])
    keep = np.sort(idx[first])
    bits = np.arange(c.n_robots, dtype=np.int64)
    inc = ((mask[keep][:, None] >> bits[None, :]) & 1).astype(bool)       # bids x robots
    conflicting = np.flatnonzero(inc.sum(axis=0) >= 2)
    if len(conflicting):
        # equal incidence columns = robots that always move together: one bit per distinct column
        packed = np.packbits(inc[:, conflicting].T, axis=1)
        seen: dict[bytes, int] = {}
        first = [seen.setdefault(row.tobytes(), j) for j, row in enumerate(packed)]
        first = sorted(set(first))
        n_bits = len(first)
        reps = conflicting[np.asarray(first, dtype=np.int64)]
        new_mask = inc[:, reps].astype(np.int64) @ np.left_shift(np.int64(1), np.arange(n_bits, dtype=np.int64))
    else:
        n_bits = 0
        new_mask = np.zeros(len(keep), dtype=np.int64)
    return task[keep].tolist(), new_mask.tolist(), value[keep].tolist(), keep.tolist(), n_bits


def _reduce_py(c: Compiled):
    """Same as the numpy path, for masks wider than int64."""
    best: dict[tuple[int, int], int] = {}
    for i in range(c.n_bids):
        if c.value[i] <= 0.0:
            continue
        key = (c.task[i], c.mask[i])
        j = best.get(key)
        if j is None or c.value[i] > c.value[j]:
            best[key] = i
    keep = sorted(best.values())
    # robot -> bitmask over kept bids (its "signature"); equal signatures share one bit
    sig: dict[int, int] = {}
    for pos, i in enumerate(keep):
        m = c.mask[i]
        while m:
            low = m & -m
            r = low.bit_length() - 1
            sig[r] = sig.get(r, 0) | (1 << pos)
            m ^= low
    new_bit: dict[int, int] = {}
    groups: dict[int, int] = {}
    for r, s in sig.items():
        if s & (s - 1) == 0:          # in one bid only: never conflicts
            continue
        if s not in groups:
            groups[s] = len(groups)
        new_bit[r] = groups[s]
    tasks, masks, values = [], [], []
    for i in keep:
        m, cm = c.mask[i], 0
        while m:
            low = m & -m
            b = new_bit.get(low.bit_length() - 1)
            if b is not None:
                cm |= 1 << b
            m ^= low
        tasks.append(c.task[i])
        masks.append(cm)
        values.append(c.value[i])
    return tasks, masks, values, keep, len(groups)


def work_estimate(masks: list[int], n_bits: int, n_layers: int) -> int:
    """States touched by the DP: each bid's supersets plus one copy of the table per layer."""
    return sum(1 << (n_bits - m.bit_count()) for m in masks) + n_layers * (1 << n_bits)


def pairs(mask: np.ndarray, value: np.ndarray, n_bits: int) -> tuple[np.ndarray, ...]:
    """For every bid and every robot set S disjoint from its coalition: (bid, S, S + coalition,
    bid value), bid-major.

    Bids with the same number of free robots are done together: their subset lists double once
    per free robot (without it, with it), so row j holds the j-th subset of every such bid."""
    bits = np.arange(n_bits, dtype=np.int64)
    member = ((mask[:, None] >> bits[None, :]) & 1).astype(bool)
    free = n_bits - member.sum(axis=1)
    counts = np.left_shift(np.int64(1), free)
    ends = np.cumsum(counts)
    offsets = ends - counts
    total = int(ends[-1])
    src = np.empty(total, dtype=np.int64)
    tgt = np.empty(total, dtype=np.int64)
    add = np.empty(total, dtype=np.float64)
    bid_of = np.empty(total, dtype=np.int64)
    for k in np.unique(free).tolist():
        rows = np.flatnonzero(free == k)
        subsets = np.zeros((1, len(rows)), dtype=np.int64)
        if k:
            weight = np.left_shift(np.int64(1), np.nonzero(~member[rows])[1].reshape(len(rows), k))
            for i in range(k):                                  # double the list with free bit i
                subsets = np.concatenate((subsets, subsets | weight[:, i][None, :]))
        pos = offsets[rows][None, :] + np.arange(1 << k, dtype=np.int64)[:, None]
        src[pos] = subsets
        tgt[pos] = subsets | mask[rows][None, :]
        add[pos] = value[rows][None, :]
        bid_of[pos] = rows[None, :]
    return bid_of, src, tgt, add


def _layers_dense(mask: np.ndarray, value: np.ndarray, bid_bounds: np.ndarray, size: int, deadline=None):
    """Layer tables for small inputs: for every bid and every robot set T, the index of T minus
    the coalition (or of a -inf sentinel when the coalition is not inside T) is computed once;
    a layer is then one gather and one max over its bids.  Past ``deadline``: the layers so far."""
    every = np.arange(size, dtype=np.int32)
    m32 = mask.astype(np.int32)[:, None]
    inside = (every[None, :] & m32) == m32
    index = np.where(inside, every[None, :] ^ m32, np.int32(size))
    cur = np.zeros(size)
    layers = [cur]
    for li in range(len(bid_bounds) - 1):
        if past(deadline):
            break
        lo, hi = bid_bounds[li], bid_bounds[li + 1]
        ext = np.append(cur, -np.inf)
        cand = (ext[index[lo:hi]] + value[lo:hi, None]).max(axis=0)
        cur = np.maximum(cur, cand)
        layers.append(cur)
    return layers, int(inside.sum())


def _layers_sparse(mask: np.ndarray, value: np.ndarray, bid_bounds: np.ndarray, n_bits: int, deadline=None):
    """Layer tables touching only each bid's supersets: bids with many free robots update strided
    views of the table (no index arrays); the rest are batched as (S, S + coalition) pairs into
    one scatter-max per task.  Past ``deadline``: the layers completed so far."""
    size = 1 << n_bits
    n_layers = len(bid_bounds) - 1
    free = n_bits - np.asarray([m.bit_count() for m in mask.tolist()], dtype=np.int64)
    min_free = max(VIEW_MIN_FREE, 1)            # a view needs at least one free axis
    small = np.flatnonzero(free < min_free)
    bid_of, src, tgt, add = (pairs(mask[small], value[small], n_bits) if len(small)
                             else (np.zeros(0, dtype=np.int64),) * 3 + (np.zeros(0),))
    pair_bounds = np.searchsorted(bid_of, np.searchsorted(small, bid_bounds))
    shape = (2,) * n_bits
    views: dict[int, tuple[tuple, tuple]] = {}
    nodes = len(src)
    free_l, mask_l, value_l = free.tolist(), mask.tolist(), value.tolist()
    big_of_layer = [[j for j in range(bid_bounds[li], bid_bounds[li + 1]) if free_l[j] >= min_free]
                    for li in range(n_layers)]
    cur = np.zeros(size)
    layers = [cur]
    for li in range(n_layers):
        new = cur.copy()
        cur_v, new_v = cur.reshape(shape), new.reshape(shape)
        for j in big_of_layer[li]:
            if past(deadline):
                return layers, nodes
            m = mask_l[j]
            ix = views.get(m)
            if ix is None:
                bits = [(m >> (n_bits - 1 - a)) & 1 for a in range(n_bits)]
                ix = (tuple(0 if b else slice(None) for b in bits), tuple(1 if b else slice(None) for b in bits))
                views[m] = ix
            out = new_v[ix[1]]
            np.maximum(out, cur_v[ix[0]] + value_l[j], out=out)
            nodes += 1 << free_l[j]
        lo, hi = pair_bounds[li], pair_bounds[li + 1]
        if hi > lo:
            np.maximum.at(new, tgt[lo:hi], cur[src[lo:hi]] + add[lo:hi])
        cur = new
        layers.append(cur)
    return layers, nodes


def solve_dp(c: Compiled, deadline: float | None = None) -> SolverOutput:
    """Exact optimum; ``nodes`` is the number of (state, bid) transitions evaluated.  Past ``deadline``: TimeUp
    with the best allocation of the tasks whose layers are done."""
    tasks, masks, values, keep, n_bits = reduce(c)
    if not keep:
        return SolverOutput((), 0)
    if n_bits > MAX_BITS:
        raise ValueError(f"dp: {n_bits} conflicting robot groups exceed {MAX_BITS}")
    size = 1 << n_bits
    task = np.asarray(tasks, dtype=np.int64)
    order = np.argsort(task, kind="stable")             # bids grouped by task
    task = task[order]
    mask = np.asarray(masks, dtype=np.int64)[order]
    value = np.asarray(values, dtype=np.float64)[order]
    local = np.asarray(keep, dtype=np.int64)[order]
    task_starts = np.flatnonzero(np.r_[True, task[1:] != task[:-1]])
    bid_bounds = np.r_[task_starts, len(mask)]
    if len(mask) * size <= DENSE_MAX:
        layers, nodes = _layers_dense(mask, value, bid_bounds, size, deadline)
    else:
        layers, nodes = _layers_sparse(mask, value, bid_bounds, n_bits, deadline)
    # walk back from the full robot set
    chosen = []
    s = size - 1
    for li in range(len(layers) - 1, 0, -1):
        now, before = layers[li], layers[li - 1]
        if now[s] == before[s]:
            continue
        b0, b1 = bid_bounds[li - 1], bid_bounds[li]
        m, v = mask[b0:b1], value[b0:b1]
        fits = (m & s) == m
        hit = np.flatnonzero(fits & (before[(s ^ m) & (size - 1)] + v == now[s]))
        if not len(hit):                                # pragma: no cover - exact float replay
            raise AssertionError("dp walk-back found no bid")
        j = b0 + hit[0]
        chosen.append(int(local[j]))
        s ^= int(mask[j])
    if len(layers) <= len(task_starts):
        raise TimeUp(chosen)
    return SolverOutput(tuple(sorted(chosen)), nodes)


class Budget(Exception):
    """The sparse DP would take more transitions than allowed."""


def solve_sparse(c: Compiled, budget: int | None = None, deadline: float | None = None) -> SolverOutput:
    """The same DP in plain Python over the robot sets actually reached (exact used sets, not
    subsets), for small instances where numpy's per-call cost dominates.  Raises Budget when it
    would evaluate more than ``budget`` (state, bid) transitions, TimeUp (with the best allocation of
    the tasks done) past ``deadline``."""
    by_task: dict[int, list[tuple[int, float, int]]] = {}
    for i in range(c.n_bids):
        v = c.value[i]
        if v > 0.0:
            by_task.setdefault(c.task[i], []).append((c.mask[i], v, i))
    states: dict[int, float] = {0: 0.0}
    choices: list[dict[int, tuple[int, int]]] = []
    nodes = 0
    for bids in by_task.values():
        nodes += len(states) * len(bids)
        if budget is not None and nodes > budget:
            raise Budget
        new = dict(states)
        choice: dict[int, tuple[int, int]] = {}
        for k, (s, v) in enumerate(states.items()):
            if not k & 0x3FF and (past(deadline) or len(new) > MAX_STATES):
                raise TimeUp(_walk_back(states, choices),
                             reason=None if past(deadline) else f"the limit of {MAX_STATES} DP states")
            for m, val, i in bids:
                if m & s:
                    continue
                ns = s | m
                nv = v + val
                if nv > new.get(ns, -1.0):
                    new[ns] = nv
                    choice[ns] = (s, i)
        states = new
        choices.append(choice)
    return SolverOutput(_walk_back(states, choices), nodes)


def _walk_back(states: dict[int, float], choices: list[dict[int, tuple[int, int]]]) -> tuple[int, ...]:
    """The bids of the best state, followed back through each task's choices."""
    s = max(states, key=states.__getitem__)
    chosen = []
    for choice in reversed(choices):
        hit = choice.get(s)
        if hit is not None:
            s, i = hit
            chosen.append(i)
    return tuple(sorted(chosen))
