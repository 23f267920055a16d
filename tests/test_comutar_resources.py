"""Paper 003 eqs. 1-5: share-restricted resources, their operators and the admission test."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from runtime.allocation.comutar.resources import CSPACE, Ledger, Resource
from runtime.errors import InputError

LINK = (1, "link")


def _link_ledger(capacity=100.0) -> Ledger:
    led = Ledger()
    led.add(Resource(1, "link", capacity=capacity, unit=" Mb/s"))
    return led


def test_the_papers_bandwidth_example_admits_10_40_30_and_refuses_40_more():
    led = _link_ledger()
    a1 = 100e3 * 100 / 1e6             # 100 kbit per sample at 100 samples/s = 10 Mb/s
    assert a1 == pytest.approx(10.0)
    for holder, mbps in (("a1", a1), ("a2", 40.0), ("a3", 30.0)):
        assert led.preallocate(holder, {LINK: mbps}, now=0.0, expires=5.0) is None
    assert led.used(LINK, 0.0) == pytest.approx(80.0)
    why = led.preallocate("a4", {LINK: 40.0}, now=0.0, expires=5.0)
    assert why is not None and "exceed the capacity 100" in why and "120" in why
    assert "a4" not in led.holds and led.refused == 1
    assert led.preallocate("a5", {LINK: 20.0}, now=0.0, expires=5.0) is None      # exactly at capacity
    assert all(led.fits(0.0).values())


def test_allocated_demands_stay_and_pre_allocations_expire():
    led = _link_ledger()
    led.preallocate("a", {LINK: 60.0}, 0.0, expires=1.0)
    led.preallocate("b", {LINK: 30.0}, 0.0, expires=1.0)
    assert led.allocate("a", 0.5) is None
    assert led.expire(0.9) == []
    assert led.expire(1.0) == ["b"]
    assert set(led.holds) == {"a"} and led.holds["a"].allocated and led.expired == 1
    assert led.preallocate("c", {LINK: 50.0}, 1.0, expires=2.0) is not None        # 60 + 50 > 100
    assert led.release("a") and not led.release("a")
    assert led.preallocate("c", {LINK: 50.0}, 1.0, expires=2.0) is None


def test_an_expired_pre_allocation_is_admitted_afresh_on_award_only_if_it_still_fits():
    led = _link_ledger()
    led.preallocate("late", {LINK: 70.0}, 0.0, expires=1.0)
    led.expire(2.0)
    led.preallocate("other", {LINK: 50.0}, 2.0, expires=3.0)
    assert led.allocate("late", 2.1, {LINK: 70.0}) is not None
    assert led.allocate("late", 2.1, {LINK: 40.0}) is None
    assert led.holds["late"].allocated


def test_a_holder_replacing_its_own_demand_is_not_counted_twice():
    led = _link_ledger()
    led.preallocate("a", {LINK: 80.0}, 0.0, 1.0)
    assert led.preallocate("a", {LINK: 90.0}, 0.0, 1.0) is None
    assert led.allocate("a", 0.0, {LINK: 100.0}) is None


def test_the_cspace_operators_are_intersection_and_non_empty():
    led = Ledger()
    key = (1, "cspace")
    led.add(Resource(1, "cspace", CSPACE))
    left = np.array([True, True, False, False])
    right = np.array([False, True, True, False])
    far_right = np.array([False, False, False, True])
    assert led.preallocate("survey", {key: None}, 0.0, 1.0) is None     # forbids nothing: the identity
    assert led.preallocate("ctrl1", {key: left}, 0.0, 1.0) is None
    assert led.preallocate("ctrl2", {key: right}, 0.0, 1.0) is None     # {1} is left
    assert np.array_equal(led.total(key, 0.0), [False, True, False, False])
    why = led.preallocate("ctrl3", {key: far_right}, 0.0, 1.0)
    assert why is not None and "no configuration left" in why


def test_constraint_functions_are_functions_of_time():
    led = _link_ledger()
    led.preallocate("ramp", {LINK: lambda t: 10.0 * t}, 0.0, 100.0)
    assert led.check({LINK: 50.0}, now=4.0) is None          # 40 + 50
    assert led.check({LINK: 50.0}, now=6.0) is not None      # 60 + 50


def test_an_environment_resource_sums_the_actions_of_every_robot():
    """Eq. 5: the double sum over robots and their actions of demands on one resource (owner 0)."""
    led = Ledger()
    chan = (0, "channel")
    led.add(Resource(0, "channel", capacity=1.0))
    for robot in (1, 2, 3):
        assert led.preallocate((robot, "stream"), {chan: 0.3}, 0.0, 9.0) is None
    why = led.check({chan: 0.2}, 0.0)
    assert why is not None and "the environment" in why
    assert led.check({(4, "cpu"): 0.1}, 0.0) == "resource cpu of robot 4 is not accounted here"


def test_a_resource_needs_an_owner_and_a_finite_capacity():
    with pytest.raises(InputError, match="owner"):
        Resource(-1, "x", capacity=1.0)
    with pytest.raises(InputError, match="capacity"):
        Resource(1, "x", capacity=float("inf"))
    with pytest.raises(InputError, match="kind"):
        Resource(1, "x", kind="vector", capacity=1.0)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 9), st.floats(0, 60), st.sampled_from(["pre", "alloc", "release", "tick"])),
                max_size=60))
def test_whatever_is_asked_the_holds_never_exceed_the_capacity(ops):
    led = _link_ledger()
    now = 0.0
    for holder, amount, op in ops:
        now += 0.1
        if op == "pre":
            led.preallocate(holder, {LINK: amount}, now, now + 0.5)
        elif op == "alloc":
            led.allocate(holder, now, {LINK: amount})
        elif op == "release":
            led.release(holder)
        else:
            led.expire(now)
        assert led.used(LINK, now) <= 100.0 + 1e-9
    led.expire(now + 1.0)
    assert not led.preallocated()
