"""Paper 000's equations in SI units against the digest's worked values, converted with 1 du = 0.01 m and
1 tu = 0.12 s (runtime/allocation/dr/model.py)."""
from __future__ import annotations

import math

import pytest

from runtime.allocation.dr import model as M

L, V_PAPER, TAU_PAPER = 2.0, 3.0, 1.0        # wu, du/tu, tu/wu
V = M.speed_from_paper(V_PAPER)               # 0.25 m/s
TAU = M.s_from_tu(TAU_PAPER)                   # 0.12 s/wu
DL = M.s_from_tu(900)                          # 108 s

# digest §2: d (du) -> wc (wu/tu), T1 (tu, one robot moves 40 wu), n900 (ideal size for 900 tu)
TABLE = [(140, .02055, 1947, 3), (180, .01613, 2480, 3), (250, .01172, 3413, 4), (280, .01049, 3813, 5),
         (330, .00893, 4480, 5), (360, .00820, 4880, 6), (400, .00739, 5413, 7)]


def test_units():
    assert V == pytest.approx(0.25) and TAU == pytest.approx(0.12) and DL == pytest.approx(108.0)
    assert M.m_from_du(140) == pytest.approx(1.4)
    assert M.capacity_from_paper(M.capacity_to_paper(0.3)) == pytest.approx(0.3)


@pytest.mark.parametrize("d, wc, t1, n900", TABLE)
def test_eq5_eq2_and_ideal_group_size_match_the_digest_table(d, wc, t1, n900):
    c = M.work_capacity(L, V, M.m_from_du(d), TAU)
    assert M.capacity_to_paper(c) == pytest.approx(wc, abs=5e-6)
    t = M.expected_time(40.0, M.group_capacity(M.ideal_capacity([c]), 0.0))
    assert t / M.TU == pytest.approx(t1, abs=0.5)
    assert M.ideal_group_size(40.0, DL, c) == n900
    # eq. 8 at the boundary: n900 robots meet the deadline, one fewer do not
    assert M.meets_deadline(40.0, M.ideal_capacity([c] * n900), DL)
    assert not M.meets_deadline(40.0, M.ideal_capacity([c] * (n900 - 1)), DL)


def test_the_error_case_believes_a_quarter_of_the_capacity():
    slow = M.work_capacity(L, M.speed_from_paper(0.8), 1.4, TAU)
    assert slow / M.work_capacity(L, V, 1.4, TAU) == pytest.approx(0.27, abs=0.01)


def test_group_capacity_not_positive_means_never():
    assert M.expected_time(40.0, 0.0) == math.inf and M.expected_time(40.0, -0.1) == math.inf
    assert not M.meets_deadline(40.0, M.group_capacity(0.1, 0.2), DL)
    assert M.expected_time(0.0, 0.0) == 0.0


def test_eq8_mid_task_counts_the_time_gone():
    c = 0.5
    assert M.meets_deadline(20.0, c, 108.0, elapsed=60.0)          # 60 + 40 <= 108
    assert not M.meets_deadline(20.0, c, 108.0, elapsed=70.0)      # 70 + 40 > 108


def test_eq9_predicts_linearly_from_the_last_measurement():
    assert M.remaining_prediction(40.0, 0.5, 30.0, 10.0) == pytest.approx(30.0)
    assert M.remaining_prediction(40.0, 0.5, 200.0, 10.0) == 0.0


@pytest.mark.parametrize("x, u", [(1.07, 0.5), (1.1, 0.412), (1.14, 1 / 3), (1.5, 0.123), (2.0, 0.065)])
def test_eq10_soft_deadline_values(x, u):
    assert M.utility_soft(x * DL, DL, 1.0) == pytest.approx(u, abs=5e-4)
    assert M.utility_soft(M.s_from_tu(x * 900), M.s_from_tu(900), 100.0) == pytest.approx(100 * u, abs=0.05)


def test_utilities_before_and_at_the_deadline():
    assert M.utility_soft(0.99 * DL, DL, 80.0) == 80.0
    assert M.utility_soft(DL, DL, 80.0) == pytest.approx(80.0)          # continuous at DL
    assert M.utility_hard(0.99 * DL, DL, 80.0) == 80.0
    assert M.utility_hard(DL, DL, 80.0) == 0.0
    assert M.utility_soft(math.inf, DL, 80.0) == 0.0
    assert set(M.UTILITIES) == {"soft", "hard"}


def test_ideal_group_size_with_interference_and_none_possible():
    c = M.work_capacity(L, V, 1.4, TAU)
    assert M.ideal_group_size(40.0, DL, c, lambda n: 0.06 * n) == 4     # interference costs a robot
    assert M.ideal_group_size(40.0, DL, c, lambda n: n * c) is None        # interference eats everything
