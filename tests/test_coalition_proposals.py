"""How coalitions are proposed and valued, where members meet, and the method's config section."""
from __future__ import annotations

import itertools
import math
from pathlib import Path

import pytest
import yaml
from hypothesis import given, settings, strategies as st

from runtime import config as C
from runtime.allocation import registry
from runtime.allocation.coalition import meeting
from runtime.allocation.coalition.proposals import propose, value_of
from runtime.errors import InputError
from runtime.tasks import Task
from runtime.tasks.rendezvous import Rendezvous

ROOT = Path(__file__).resolve().parents[1]


def task(k: int, value: float = 100.0) -> Task:
    return Task(1, "rendezvous", Rendezvous(0.0, 0.0, k, value))


travels = st.dictionaries(st.integers(1, 9), st.floats(0, 60), min_size=1, max_size=9)


@settings(max_examples=200, deadline=None)
@given(travels, st.integers(1, 4), st.integers(1, 4), st.floats(10, 200))
def test_each_coalition_has_one_proposer_and_the_best_is_always_proposed(travel, k, m, v):
    t = task(k, v)
    robots = sorted(travel)
    proposed = {}
    for me in robots:
        bids = propose(me, t, travel[me], {r: travel[r] for r in robots if r != me}, m)
        assert len(bids) <= m
        for rs, value in bids:
            assert rs not in proposed, "two leaders proposed the same coalition"
            assert min(rs) == me and len(rs) == k and value > 0
            assert math.isclose(value, v - k * max(travel[r] for r in rs))
            proposed[rs] = value
    every = {rs: value_of(t, [travel[r] for r in rs]) for rs in itertools.combinations(robots, k)}
    best = max(every.values(), default=-math.inf)
    if best > 0:
        assert math.isclose(max(proposed.values()), best)
    else:
        assert not proposed


def test_a_leader_needs_enough_partners_and_a_finite_travel():
    t = task(3)
    assert propose(5, t, 1.0, {6: 1.0}, 3) == []                   # one partner above it: no 3-robot coalition
    assert propose(1, t, math.inf, {2: 1.0, 3: 1.0}, 3) == []
    assert propose(1, task(1), 2.0, {}, 3) == [((1,), 98.0)]
    assert propose(1, task(2, 10.0), 6.0, {2: 1.0}, 3) == []        # 10 - 2 * 6 < 0: not worth doing


@pytest.mark.parametrize("k", range(2, 9))
def test_ring_slots_keep_neighbours_apart(k):
    r, gap = 0.17, 0.1
    spots = [meeting.slot((1.0, -2.0), k, i, r, gap) for i in range(k)]
    d = min(math.dist(a, b) for a, b in itertools.combinations(spots, 2))
    assert math.isclose(d, 2 * r + gap, rel_tol=1e-9)
    assert all(math.isclose(math.dist(s, (1.0, -2.0)), meeting.ring_radius(k, r, gap)) for s in spots)
    assert meeting.slot((1.0, -2.0), 1, 0, r, gap) == (1.0, -2.0)


def test_members_get_the_slots_on_their_side():
    pos = {7: (5.0, 0.1), 3: (-5.0, 0.0)}                            # 7 from the east, 3 from the west
    assert meeting.ring_order((0.0, 0.0), (3, 7), pos) == (7, 3)        # slot 0 points east
    pos = {1: (0.0, 5.0), 2: (-4.0, -3.0), 3: (4.0, -3.0)}
    order = meeting.ring_order((0.0, 0.0), (1, 2, 3), pos)
    for i, r in enumerate(order):
        sx, sy = meeting.slot((0.0, 0.0), 3, i, 0.17, 0.1)
        assert math.dist((sx, sy), pos[r]) < min(math.dist((sx, sy), pos[o]) for o in pos if o != r)
    assert meeting.ring_order((0.0, 0.0), (4, 2), {}) == (2, 4)


def _robot_yaml(tmp_path, allocation) -> Path:
    data = yaml.safe_load((ROOT / "configs" / "robots" / "create2_coalition.yaml").read_text())
    data["allocation"] = allocation
    p = tmp_path / "robot.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def test_the_config_section_is_the_options_dataclass(tmp_path):
    assert "coalition" in registry.names()
    m = registry.method("coalition")
    assert m.task_kinds == ("rendezvous",) and Path(m.dialect).is_file()
    cfg = C.load_robot(_robot_yaml(tmp_path, {"method": "coalition", "bid_window": 0.5, "max_candidates": 2}))
    assert isinstance(cfg.allocation, m.options) and cfg.allocation.bid_window == 0.5
    cfg = C.load_robot(ROOT / "configs" / "robots" / "create2_coalition.yaml")
    assert cfg.allocation.method == "coalition"
    with pytest.raises(InputError) as e:
        C.load_robot(_robot_yaml(tmp_path, {"method": "coalition", "bid_windw": 0.5}))
    assert "allocation.bid_windw" in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(InputError) as e:
        C.load_robot(_robot_yaml(tmp_path, {"method": "coalition", "wdp": "greedy"}))
    assert "allocation.wdp" in str(e.value)
