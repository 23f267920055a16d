"""Winner determination: every method is exact and feasible (brute force and HiGHS agree)."""
from __future__ import annotations

import itertools
import math
import random

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.optimize import Bounds, LinearConstraint, milp

from runtime.allocation.coalition import wdp_bounds, wdp_dp, wdp_search
from runtime.allocation.coalition import winner_determination as wd
from runtime.allocation.coalition.wdp_model import Compiled, Problem, TaskBid, compile_problem
from runtime.errors import InputError
from sitl.experiments.wdp_tables import make_problem

EXACT = ("auto", "idastar", "bfs", "dp", "sparse", "milp")

# paper 001, Table 2
TABLE2 = Problem((1, 2, 3), ("t1", "t2", "t3"), (
    TaskBid("t1", (1, 2), 3), TaskBid("t1", (2, 3), 4), TaskBid("t1", (3,), 2),
    TaskBid("t2", (1, 2), 4), TaskBid("t2", (2,), 5), TaskBid("t2", (3,), 3),
    TaskBid("t3", (1, 3), 4), TaskBid("t3", (2, 3), 4), TaskBid("t3", (3,), 8)))


def brute_force(p: Problem) -> float:
    """Best total over every subset of bids that is feasible."""
    best = 0.0
    for k in range(len(p.bids) + 1):
        for combo in itertools.combinations(range(len(p.bids)), k):
            if wd.check_feasible(p, combo):
                best = max(best, math.fsum(p.bids[i].value for i in combo))
    return best


def highs_value(p: Problem) -> float:
    """The integer program written out here, independently of wdp_milp."""
    if not p.bids:
        return 0.0
    rows = list(p.robots) + list(p.tasks)
    a = np.zeros((len(rows), len(p.bids)))
    for j, b in enumerate(p.bids):
        a[rows.index(b.task) if b.task not in p.robots else len(p.robots) + list(p.tasks).index(b.task), j] = 1
        for r in b.robots:
            a[list(p.robots).index(r), j] = 1
    res = milp(-np.array([b.value for b in p.bids]), constraints=LinearConstraint(a, -np.inf, 1),
               integrality=np.ones(len(p.bids)), bounds=Bounds(0, 1))
    assert res.status == 0
    return -res.fun


@st.composite
def problems(draw, max_robots=6, max_tasks=5, max_bids=10):
    n_r = draw(st.integers(1, max_robots))
    n_t = draw(st.integers(1, max_tasks))
    robots = tuple(range(100, 100 + n_r))
    tasks = tuple(f"t{i}" for i in range(n_t))
    value = st.one_of(st.integers(0, 30).map(float), st.floats(0, 50, allow_nan=False), st.sampled_from([0.0, 1.0, 2.5]))
    bids = draw(st.lists(st.builds(
        TaskBid, st.sampled_from(tasks),
        st.lists(st.sampled_from(robots), min_size=1, max_size=n_r, unique=True).map(tuple), value),
        max_size=max_bids))
    return Problem(robots, tasks, tuple(bids))


@settings(max_examples=150, deadline=None)
@given(problems())
def test_every_method_matches_brute_force_and_highs(p):
    ref = brute_force(p)
    assert math.isclose(highs_value(p), ref, rel_tol=1e-9, abs_tol=1e-7)
    for method in EXACT:
        res = wd.solve(p, method)
        assert wd.check_feasible(p, res.winners), method
        assert math.isclose(res.value, ref, rel_tol=1e-9, abs_tol=1e-7), (method, res.value, ref)
        assert res.value == math.fsum(p.bids[b].value for b in res.winners)
        assert res.assignment == {p.bids[b].task: p.bids[b].robots for b in res.winners}
        assert not res.capped


@settings(max_examples=60, deadline=None)
@given(problems(max_robots=8, max_tasks=4, max_bids=12).filter(lambda p: p.bids))
def test_single_robot_bids_use_the_assignment_solver(p):
    single = Problem(p.robots, p.tasks, tuple(TaskBid(b.task, b.robots[:1], b.value) for b in p.bids))
    ref = brute_force(single)
    res = wd.solve(single, "assignment")
    assert wd.check_feasible(single, res.winners)
    assert math.isclose(res.value, ref, rel_tol=1e-9, abs_tol=1e-7)


def test_assignment_refuses_coalitions():
    with pytest.raises(InputError, match="single robot"):
        wd.solve(TABLE2, "assignment")


@pytest.mark.parametrize("method", EXACT)
def test_paper_table2_optimum_is_13(method):
    res = wd.solve(TABLE2, method)
    assert res.value == 13.0
    assert res.assignment == {"t2": (2,), "t3": (3,)}


def test_idastar_thresholds_follow_the_paper_example():
    c = compile_problem(TABLE2)
    lv = wdp_search.levels(c)
    h = wdp_search.Heuristic(c.n_robots, lv)
    assert h(0, 0) == 15.0                      # R1: 4/2, R2: 5/1, R3: 8/1
    out = wdp_search.solve_idastar(c)
    assert out.iterations == 2                  # threshold 15, then 13 (paper, Figure 2)
    assert c.total(out.chosen) == 13.0


@settings(max_examples=100, deadline=None)
@given(problems(max_robots=7, max_tasks=4, max_bids=9))
def test_heuristic_never_underestimates(p):
    """h at the root is at least the optimum, and at every depth at least what the remaining
    tasks can add with the robots not yet used."""
    c = compile_problem(p)
    lv = wdp_search.levels(c)
    h = wdp_search.Heuristic(c.n_robots, lv)
    assert h(0, 0) >= brute_force(p) - 1e-9
    for d in range(len(lv) + 1):
        rest = [b for level in lv[d:] for b in level]
        for used in range(1 << c.n_robots):
            best = 0.0
            for k in range(len(rest) + 1):
                for combo in itertools.combinations(rest, k):
                    ms = [m for _, m, _ in combo]
                    if any(m & used for m in ms) or sum(ms) != _or(ms):
                        continue
                    if len({c.task[i] for i, _, _ in combo}) < len(combo):
                        continue
                    best = max(best, sum(v for _, _, v in combo))
            assert h(d, used) >= best - 1e-9


def _or(ms):
    out = 0
    for m in ms:
        out |= m
    return out


def test_bfs_generates_the_whole_tree():
    # two tasks, bids {1} and {1,2} for A, {2} for B: the tree is
    # root -> {1}, {1,2}, dummy ; then B under each: {1}->{2},dummy ; {1,2}->dummy ; dummy->{2},dummy
    p = Problem((1, 2), ("A", "B"), (TaskBid("A", (1,), 1), TaskBid("A", (1, 2), 3), TaskBid("B", (2,), 1)))
    out = wdp_search.solve_bfs(compile_problem(p))
    assert out.nodes == 3 + 5
    assert compile_problem(p).total(out.chosen) == 3.0


def test_node_caps_stop_the_search_with_a_feasible_answer():
    rng = random.Random(3)
    p = make_problem(rng, 10, 10, 60, "uniform")
    exact = wd.solve(p, "dp").value
    for method in ("idastar", "bfs"):
        res = wd.solve(p, method, node_limit=50)
        assert res.capped and res.nodes == 50
        assert wd.check_feasible(p, res.winners)
        assert res.value <= exact + 1e-9
        assert res.to_json()["capped"] is True


@pytest.mark.parametrize("dist, n_tasks, n_bids", [("random", 10, 50), ("random", 20, 500), ("uniform", 15, 400),
                                                   ("uniform", 20, 1200)])
def test_paper_sized_instances_dp_sparse_auto_agree_with_highs(dist, n_tasks, n_bids):
    rng = random.Random(f"{dist}{n_tasks}{n_bids}")
    for _ in range(2 if n_bids < 1000 else 1):
        p = make_problem(rng, 10, n_tasks, n_bids, dist)
        ref = wd.solve(p, "milp").value
        for method in ("auto", "dp") + (("sparse",) if n_bids <= 50 else ()):
            res = wd.solve(p, method)
            assert wd.check_feasible(p, res.winners)
            assert math.isclose(res.value, ref, rel_tol=1e-9), (method, res.value, ref)


def test_auto_splits_independent_parts_and_handles_many_robots():
    """Two disjoint fleets of 30 robots each (60 in all): auto solves them apart."""
    rng = random.Random(9)
    robots = tuple(range(1, 61))
    bids = []
    for half in (0, 30):
        for t in range(6):
            for _ in range(8):
                bids.append(TaskBid(f"{half}-{t}", tuple(rng.sample(robots[half:half + 30], 3)), float(rng.randint(1, 50))))
    p = Problem(robots, tuple(sorted({b.task for b in bids})), tuple(bids))
    res = wd.solve(p, "auto")
    assert res.parts == 2
    assert wd.check_feasible(p, res.winners)
    assert math.isclose(res.value, wd.solve(p, "milp").value, rel_tol=1e-9)


def test_auto_falls_back_to_highs_when_the_dp_table_is_too_big():
    rng = random.Random(4)
    robots = tuple(range(1, 31))
    bids = tuple(TaskBid(t, tuple(rng.sample(robots, 2)), float(rng.randint(1, 9))) for t in range(8) for _ in range(25))
    p = Problem(robots, tuple(range(8)), bids)
    res = wd.solve(p, "auto")
    assert "milp" in res.method
    assert math.isclose(res.value, wd.solve(p, "milp").value, rel_tol=1e-9)
    with pytest.raises(InputError, match="exceed"):
        wd.solve(p, "dp")


def test_dp_reduction_merges_robots_that_move_together():
    # robots 1 and 2 always bid together, robot 4 is in one bid only: 2 bits remain (group {1,2}, robot 3)
    c = Compiled(4, 2, (0, 0, 1), (0b0011, 0b0111, 0b1100), (5.0, 6.0, 4.0))
    tasks, masks, values, keep, bits = wdp_dp.reduce(c)
    assert bits == 2 and keep == [0, 1, 2]
    assert masks[0] != masks[1] and masks[2] & masks[1] and not masks[2] & masks[0]
    py = wdp_dp._reduce_py(c)
    assert (py[0], py[2], py[3], py[4]) == (tasks, values, keep, bits)
    assert [m.bit_count() for m in py[1]] == [m.bit_count() for m in masks]


def test_dp_reduction_drops_worthless_and_repeated_bids():
    c = Compiled(2, 1, (0, 0, 0, 0), (1, 1, 3, 2), (2.0, 5.0, 0.0, 1.0))
    _, _, values, keep, _ = wdp_dp.reduce(c)
    assert keep == [1, 3] and values == [5.0, 1.0]


@settings(max_examples=80, deadline=None)
@given(problems(max_robots=8, max_tasks=5, max_bids=14))
def test_bound_pruning_keeps_an_optimal_allocation(p):
    c = compile_problem(p)
    pruned = wdp_bounds.prune(c)
    assert set(pruned.bid_ids) <= set(c.bid_ids)
    ref = brute_force(p)
    sub = Problem(p.robots, p.tasks, tuple(p.bids[i] for i in pruned.bid_ids))
    assert math.isclose(brute_force(sub), ref, rel_tol=1e-9, abs_tol=1e-7)


def test_sparse_budget_raises_then_auto_uses_the_table(monkeypatch):
    rng = random.Random(5)
    c = compile_problem(make_problem(rng, 10, 10, 40, "uniform"))
    with pytest.raises(wdp_dp.Budget):
        wdp_dp.solve_sparse(c, budget=10)
    assert wd.solve_compiled(c, "auto")[1] == "auto:sparse"
    monkeypatch.setattr(wd, "SPARSE_BUDGET", 10)
    out, name = wd.solve_compiled(c, "auto")
    assert name == "auto:dp"
    assert c.total(out.chosen) == c.total(wdp_dp.solve_sparse(c).chosen)


def test_empty_and_zero_problems():
    empty = Problem((1,), ("a",), ())
    zero = Problem((1,), ("a",), (TaskBid("a", (1,), 0.0),))
    for p in (empty, zero):
        for method in EXACT:
            res = wd.solve(p, method)
            assert res.value == 0.0 and wd.check_feasible(p, res.winners)


def test_unknown_method_is_an_input_error():
    with pytest.raises(InputError, match="method 'fast'"):
        wd.solve(TABLE2, "fast")


@pytest.mark.parametrize("dense_max, view_min_free", [(0, 0), (0, 99), (0, 2)],
                         ids=["views only", "pairs only", "mixed"])
def test_every_dp_layer_kernel_is_exact(monkeypatch, dense_max, view_min_free):
    monkeypatch.setattr(wdp_dp, "DENSE_MAX", dense_max)
    monkeypatch.setattr(wdp_dp, "VIEW_MIN_FREE", view_min_free)

    @settings(max_examples=60, deadline=None)
    @given(problems(max_robots=7, max_tasks=5, max_bids=11))
    def check(p):
        res = wd.solve(p, "dp")
        assert wd.check_feasible(p, res.winners)
        assert math.isclose(res.value, brute_force(p), rel_tol=1e-9, abs_tol=1e-7)

    check()
