"""Param / ParamTable: names, types, range and finite checks; a refused set changes nothing."""
from __future__ import annotations

import math

import pytest
from hypothesis import given, settings, strategies as st

from runtime.comms.params import MAX_EXACT_INT, Param, ParamTable, float32
from runtime.errors import InputError


class Store:
    """Where the robot keeps its values; the table only reaches them through get/set."""

    def __init__(self, **values):
        self.values = dict(values)
        self.applied: list = []

    def param(self, name, type_, lo, hi, key=None, desc="a value"):
        key = key or name

        def setter(v):
            self.applied.append((key, v))
            self.values[key] = v

        return Param(name, type_, lo, hi, desc, lambda: self.values[key], setter)


@pytest.fixture
def store():
    return Store(CTL_CRUISE_SPD=0.5, ALLOC_RETRIES=3)


@pytest.fixture
def table(store):
    return ParamTable([store.param("CTL_CRUISE_SPD", float, 0.0, 2.0),
                       store.param("ALLOC_RETRIES", int, 0, 10)])


def test_order_gives_the_index(table):
    assert len(table) == 2
    assert table.index("CTL_CRUISE_SPD") == 0 and table.index("ALLOC_RETRIES") == 1
    assert table.index("ctl_cruise_spd") == 0                  # names are upper case: matched so
    assert table.index("NOPE") is None and table.index(None) is None
    assert table.by_index(1).name == "ALLOC_RETRIES"
    assert table.by_index(2) is None and table.by_index(-1) is None
    assert [p.name for p in table] == ["CTL_CRUISE_SPD", "ALLOC_RETRIES"]


def test_set_in_range_applies_and_reports_the_value_now(table, store):
    assert table.set("CTL_CRUISE_SPD", 1.25) == (True, 1.25, "")
    assert store.values["CTL_CRUISE_SPD"] == 1.25
    ok, value, reason = table.set("ALLOC_RETRIES", 7.0)          # a float on the wire, an int here
    assert (ok, value, reason) == (True, 7.0, "")
    assert store.applied[-1] == ("ALLOC_RETRIES", 7) and type(store.applied[-1][1]) is int
    assert table.set("CTL_CRUISE_SPD", 2.0)[0] and table.set("CTL_CRUISE_SPD", 0.0)[0]   # bounds included


@pytest.mark.parametrize("name, value, why", [
    ("CTL_CRUISE_SPD", 2.5, "out of range 0..2"),
    ("CTL_CRUISE_SPD", -0.1, "out of range"),
    ("CTL_CRUISE_SPD", math.nan, "finite"),
    ("CTL_CRUISE_SPD", math.inf, "finite"),
    ("CTL_CRUISE_SPD", "1.0", "expected a number"),
    ("CTL_CRUISE_SPD", True, "expected a number"),
    ("ALLOC_RETRIES", 2.5, "expected an integer"),
    ("ALLOC_RETRIES", 11, "out of range 0..10"),
])
def test_refused_set_leaves_the_value_unchanged(table, store, name, value, why):
    before = dict(store.values)
    ok, now, reason = table.set(name, value)
    assert not ok and why in reason and name in reason and "\n" not in reason
    assert store.values == before and store.applied == []
    assert now == before[name]


def test_unknown_name_and_a_setter_that_refuses(table, store):
    ok, now, reason = table.set("NOPE", 1.0)
    assert not ok and math.isnan(now) and "no such parameter" in reason

    def refuse(v):
        raise RuntimeError("base busy")

    t = ParamTable([Param("X", float, 0, 1, "x", lambda: 0.25, refuse)])
    assert t.set("X", 0.5) == (False, 0.25, "X: not applied (RuntimeError: base busy)")


def test_value_is_what_travels_in_a_float32(store):
    t = ParamTable([store.param("CTL_CRUISE_SPD", float, 0.0, 2.0)])
    store.values["CTL_CRUISE_SPD"] = 0.1
    assert t.value(t.by_index(0)) == float32(0.1) != 0.1
    broken = Param("BROKEN", float, 0, 1, "getter raises", lambda: 1 / 0, lambda v: None)
    t.add(broken)
    assert math.isnan(t.value(broken))


@pytest.mark.parametrize("kwargs, why", [
    (dict(name="lower_case"), "A-Z"),
    (dict(name="A" * 17), "1-16"),
    (dict(name=""), "1-16"),
    (dict(name="1ABC"), "starting with a letter"),
    (dict(type=str), "float or int"),
    (dict(lo=2.0, hi=1.0), "lo <= hi"),
    (dict(lo=math.nan), "lo <= hi"),
    (dict(type=int, lo=0, hi=2 ** 25), "float32-exact"),
    (dict(type=int, lo=0.5, hi=2), "integral"),
    (dict(description="two\nlines"), "one-line"),
    (dict(get=None), "callable"),
])
def test_bad_definitions_are_one_line_input_errors(kwargs, why):
    args = dict(name="GOOD_NAME", type=float, lo=0.0, hi=1.0, description="d", get=lambda: 0.0, set=lambda v: None)
    args.update(kwargs)
    with pytest.raises(InputError) as e:
        Param(**args)
    assert why in str(e.value) and "\n" not in str(e.value)


def test_duplicate_names_are_refused(store):
    t = ParamTable([store.param("CTL_CRUISE_SPD", float, 0.0, 2.0)])
    with pytest.raises(InputError, match="defined twice"):
        t.add(store.param("CTL_CRUISE_SPD", float, 0.0, 1.0))
    with pytest.raises(InputError, match="expected a Param"):
        t.add("CTL_CRUISE_SPD")


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-2 ** 40, 2 ** 40),
                 st.none(), st.text(max_size=5), st.booleans()))
def test_any_value_either_applies_within_range_or_changes_nothing(value):
    store = Store(F=0.5, I=3)
    t = ParamTable([store.param("F", float, -1.0, 1.0), store.param("I", int, -MAX_EXACT_INT, MAX_EXACT_INT)])
    for name, lo, hi in (("F", -1.0, 1.0), ("I", -MAX_EXACT_INT, MAX_EXACT_INT)):
        before = store.values[name]
        ok, now, reason = t.set(name, value)
        if ok:
            assert lo <= store.values[name] <= hi and reason == ""
            assert now == float32(store.values[name])
        else:
            assert store.values[name] == before and reason
