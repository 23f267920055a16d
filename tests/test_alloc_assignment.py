"""Assignment problem model: optimum, costs, validation, and the task book agents share."""
from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, strategies as st

from runtime.allocation.formation import assignment as A


def brute_force(c) -> float:
    n = len(c)
    return min(sum(c[r][p[r]] for r in range(n)) for p in itertools.permutations(range(n)))


square = st.integers(1, 6).flatmap(
    lambda n: st.lists(st.lists(st.integers(0, 50), min_size=n, max_size=n), min_size=n, max_size=n))


@given(square)
def test_hungarian_is_the_brute_force_optimum(c):
    assignment, total = A.hungarian(c)
    assert A.is_permutation(assignment, len(c))
    assert total == brute_force(c)
    assert A.global_cost(c, assignment) == total


def test_straight_line_costs():
    c = A.straight_line_costs([[0, 0], [3, 4]], [[3, 4], [0, 0], [6, 8]])
    assert c.shape == (2, 3)
    assert np.allclose(c, [[5, 0, 10], [0, 5, 5]])


def test_percent_error_and_global_cost():
    assert A.percent_error(5.0, 3.0) == pytest.approx(66.6667, abs=1e-3)
    assert A.percent_error(0.0, 0.0) == 0.0
    assert A.percent_error(1.0, 0.0) == math.inf
    assert A.global_cost([[1, 2], [3, 4]], [1, -1]) == 2


def test_is_permutation():
    assert A.is_permutation([1, 0, 2], 3)
    assert not A.is_permutation([1, 1, 2], 3)
    assert not A.is_permutation([1, None, 0], 3)
    assert not A.is_permutation([0, 1], 3)


@pytest.mark.parametrize("costs, words", [
    ([], "non-empty"),
    ("x", "non-empty list"),
    ([[1, 2], [3]], "row 1: has 1 entries, expected 2"),
    ([[1, 2, 3], [4, 5, 6]], "row 0: has 3 entries, expected 2"),
    ([[1, -2], [3, 4]], "costs[0][1]: expected a non-negative"),
    ([[1, float("nan")], [3, 4]], "costs[0][1]: expected a finite"),
    ([[1, 2], [float("inf"), 4]], "costs[1][0]: expected a finite"),
    ([[1, "2"], [3, 4]], "costs[0][1]: expected a number"),
    ([[True, 2], [3, 4]], "costs[0][0]: expected a number"),
    ([[10 ** 400, 2], [3, 4]], "costs[0][0]: expected a finite"),
    ([5, 6], "row 0: expected a list"),
])
def test_check_costs_names_the_problem(costs, words):
    with pytest.raises(ValueError, match=words.replace("[", r"\[").replace("]", r"\]")):
        A.check_costs(costs)


def test_task_book_caches_finite_costs_only():
    calls = []
    state = {"ready": False}

    def cost(t):
        calls.append(t)
        return 2.0 * t if state["ready"] else math.inf

    book = A.TaskBook(cost)
    assert book.cost(3) == math.inf
    state["ready"] = True
    assert book.cost(3) == 6.0
    assert book.cost(3) == 6.0
    assert calls == [3, 3]


def test_task_book_rejects_contradictions():
    book = A.TaskBook(lambda t: 1.0)
    assert book.learn(0, 1.0, 2.0, 2)
    assert not book.complete
    assert not book.learn(1, 0.0, 0.0, 3)       # another size for the same set
    assert book.learn(1, 0.0, 0.0, 2)
    assert book.complete
    assert not book.learn(7, 0.0, 0.0)          # a third task in a set of two
    assert book.positions == {0: (1.0, 2.0), 1: (0.0, 0.0)}


def test_task_book_survives_a_cost_function_that_raises():
    book = A.TaskBook(lambda t: [1.0][t])
    assert book.cost(0) == 1.0
    assert book.cost(5) == math.inf
