"""BS and RTMA in closed form (task-proposing deferred acceptance): the agents end in exactly that
matching whatever the message order, loss or duplication; the matching is stable; RTMA is optimal on
every 2 x 2 problem."""
from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from runtime.allocation.formation.assignment import hungarian, is_permutation
from runtime.allocation.formation.deferred_acceptance import (bs_outcome, deferred_acceptance, rtma_bids,
                                                    rtma_outcome)
from runtime.allocation.bus import InMemoryBus
from runtime.allocation.formation.simulate import BusParams, make_agents, solve

OUTCOME = {"bs": bs_outcome, "rtma": rtma_outcome}


def real_instance(seed: int, n: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    r, t = rng.uniform(0, 1000, (n, 2)), rng.uniform(0, 1000, (n, 2))
    return np.hypot(r[:, None, 0] - t[None, :, 0], r[:, None, 1] - t[None, :, 1])


def blocking_pairs(task_key, robot_key, held):
    """(robot, task) pairs that would both rather be matched to each other."""
    n = len(held)
    holder = {t: r for r, t in enumerate(held)}
    out = []
    for i, j in itertools.product(range(n), range(n)):
        if held[i] == j:
            continue
        robot_prefers = (robot_key[i, j], j) < (robot_key[i, held[i]], held[i])
        task_prefers = (task_key[i, j], i) < (task_key[holder[j], j], holder[j])
        if robot_prefers and task_prefers:
            out.append((i, j))
    return out


@pytest.mark.parametrize("method", ["bs", "rtma"])
@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(1, 12), lossy=st.booleans())
def test_agents_end_in_the_closed_form_matching(method, seed, n, lossy):
    c = real_instance(seed, n)
    bus = BusParams(jitter=0.009, drop=0.1, duplicate=0.1, seed=seed) if lossy else BusParams()
    r = solve(method, c, bus=bus, until=3600)
    assert r.converged
    assert r.assignment == OUTCOME[method](c)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(1, 15), integer=st.booleans())
def test_matching_is_a_permutation_with_no_blocking_pair(seed, n, integer):
    rng = np.random.default_rng(seed)
    task_key = rng.integers(0, 5, (n, n)) if integer else rng.uniform(0, 1, (n, n))   # integers: ties
    robot_key = rng.integers(0, 5, (n, n)) if integer else rng.uniform(0, 1, (n, n))
    held = deferred_acceptance(task_key, robot_key)
    assert is_permutation(held, n)
    assert blocking_pairs(task_key, robot_key, held) == []


def test_task_optimal_among_all_stable_matchings():
    """Deferred acceptance with tasks proposing gives every task its best stable partner."""
    rng = np.random.default_rng(3)
    for _ in range(40):
        n = int(rng.integers(2, 6))
        tk, rk = rng.uniform(0, 1, (n, n)), rng.uniform(0, 1, (n, n))
        held = deferred_acceptance(tk, rk)
        stable = [list(p) for p in itertools.permutations(range(n)) if not blocking_pairs(tk, rk, list(p))]
        assert held in stable
        for other in stable:
            for i in range(n):      # the robot each task gets is at least as good for the task
                robot_here = held.index(i)
                robot_there = other.index(i)
                assert tk[robot_here, i] <= tk[robot_there, i]


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(0, 1e4, allow_nan=False), min_size=4, max_size=4))
def test_rtma_is_optimal_on_every_two_by_two(values):
    c = np.array(values).reshape(2, 2)
    a = rtma_outcome(c)
    assert c[[0, 1], a].sum() <= hungarian(c)[1] + 1e-9 * (1 + c.sum())


def greedy(matrix: np.ndarray) -> list[int]:
    """Repeatedly match the smallest entry whose robot and task are both free."""
    n = matrix.shape[0]
    held, free_r, free_t = [-1] * n, set(range(n)), set(range(n))
    for idx in np.argsort(matrix, axis=None, kind="stable"):
        i, j = divmod(int(idx), n)
        if i in free_r and j in free_t:
            held[i] = j
            free_r.discard(i)
            free_t.discard(j)
    return held


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(1, 20))
def test_bs_is_greedy_on_costs_and_rtma_greedy_on_the_double_centred_costs(seed, n):
    """Both sides rank by one matrix, so the stable matching is unique and greedy finds it: BS on the
    costs, RTMA on costs minus row means minus column means (what its two rules amount to)."""
    c = real_instance(seed, n)
    assert bs_outcome(c) == greedy(c)
    assert rtma_outcome(c) == greedy(c - c.mean(axis=1, keepdims=True) - c.mean(axis=0, keepdims=True))


def test_rtma_bids_are_cost_minus_the_robots_mean():
    c = np.array([[1.0, 3.0], [10.0, 2.0]])
    assert rtma_bids(c).tolist() == [[-1.0, 1.0], [4.0, -4.0]]


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match="n x n"):
        deferred_acceptance(np.zeros((2, 3)), np.zeros((2, 3)))


class _Float32Bus(InMemoryBus):
    """The in-memory bus with every float field rounded to IEEE single, as the MAVLink dialect carries it."""

    def send(self, msgs, now):
        out = []
        for m in msgs:
            changes = {f.name: float(np.float32(getattr(m, f.name))) for f in dataclasses.fields(m)
                       if isinstance(getattr(m, f.name), float)}
            out.append(dataclasses.replace(m, **changes))
        return super().send(out, now)


@pytest.mark.parametrize("method", ["bs", "rtma"])
@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(2, 9), offset=st.floats(0.1, 50.0))
def test_tied_bids_through_single_precision_still_allocate_every_task(method, seed, n, offset):
    """Robot 2 sits behind robot 1 (every path of 2 passes 1): its costs are robot 1's plus a constant,
    so RTMA bids tie exactly and BS bids keep one order.  Bids cross the wire as float32; a robot that
    compared its own float64 bid with them could find no "worse" bid and drop a task (seen driving
    6 robots in pybullet)."""
    c = real_instance(seed, n)
    c[1] = c[0] + offset
    agents = make_agents(method, c)
    bus = _Float32Bus(agents)
    stop = lambda: all(a.converged for a in agents.values())            # noqa: E731
    bus.send(agents[1].start({j: (float(j), 0.0) for j in range(n)}, 0.0), 0.0)
    bus.run(600.0, stop=stop)
    held = [agents[r].assignment for r in sorted(agents)]
    assert is_permutation(held, n)
