"""simulate.solve: what it counts (messages, Lamport rounds) and when it stops."""
from __future__ import annotations

import numpy as np
import pytest

from runtime.allocation.formation.assignment import hungarian, is_permutation
from runtime.allocation.formation.simulate import BusParams, solve


def costs(seed=1, n=8):
    return np.random.default_rng(seed).uniform(0, 100, (n, n))


@pytest.mark.parametrize("method", ["bs", "rtma"])
def test_rounds_and_messages_do_not_depend_on_the_delay(method):
    fast = solve(method, costs(), bus=BusParams(delay=0.01))
    slow = solve(method, costs(), bus=BusParams(delay=0.04))
    assert (fast.assignment, fast.messages, fast.rounds) == (slow.assignment, slow.messages, slow.rounds)
    assert fast.rounds >= 3        # announce -> bid -> award at least


def test_messages_are_what_the_agents_sent():
    r = solve("bs", [[1.0]])
    # one robot: it announces its only task (a broadcast nobody hears) and wins it itself
    assert r.messages == 1 and r.assignment == [0] and r.converged
    r = solve("bs", [[1.0, 2.0], [2.0, 1.0]])
    # 2 announces + 2 bids + 1 award + 1 acknowledgement (robot 1 wins task 0 itself)
    assert r.messages == 6 and r.assignment == [0, 1]


def test_hungarian_is_centralised():
    c = costs()
    r = solve("hungarian", c)
    assert r.messages == 0 and r.rounds == 0 and r.cost == pytest.approx(hungarian(c)[1])


def test_not_converged_is_reported():
    r = solve("auction", costs(n=10), until=0.05)
    assert not r.converged
    assert r.sim_time <= 0.05 + 1e-9


def test_unknown_method_and_bad_problem():
    with pytest.raises(ValueError, match="method"):
        solve("magic", costs())
    with pytest.raises(ValueError, match="give costs"):
        solve("bs")
    with pytest.raises(ValueError, match="non-negative"):
        solve("bs", [[-1.0]])


def test_positions_label_the_tasks():
    robots, tasks = [(0, 0), (10, 0)], [(9, 0), (1, 0)]
    r = solve("auction", robots=robots, tasks=tasks)
    assert r.assignment == [1, 0] and r.cost == pytest.approx(2.0)
    assert is_permutation(r.assignment, 2)
