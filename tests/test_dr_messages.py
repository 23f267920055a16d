"""The dr family's wire messages: its block of the dialect, round trips, validation once at decode, and random,
truncated, bit-flipped and nonsense input that never makes the agent raise and is counted."""
from __future__ import annotations

import dataclasses
import random
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from hypothesis import given, settings, strategies as st

from runtime.messages import why_invalid
from runtime.allocation.dr import messages as W
from runtime.comms import codec, dialect
from runtime.messages import RobotState

from tests.codec_util import damage, decode, frame
from tests.dr_util import busy_fleet

ROOT = Path(__file__).resolve().parents[1]
XML = ROOT / "runtime" / "allocation" / "dr" / "dr.xml"


@pytest.fixture(scope="module")
def mod():
    return dialect.load()


robot = st.integers(1, 250)
dest = st.integers(0, 250)
task = st.integers(1, 250).flatmap(lambda o: st.integers(0, 0xFFFF).map(lambda n: o << 16 | n))
u32 = st.integers(0, 0xFFFFFFFF)
seq = st.integers(1, 0xFFFFFFFF)
amount = st.floats(0, 1e6, width=32)
number = st.floats(-1e6, 1e6, width=32)
members = st.lists(robot, min_size=0, max_size=W.MAX_MEMBERS - 1, unique=True)


def _alive(sender, dest, task, *values, others):
    return W.DrLeaderAlive(sender, dest, task, *values, tuple([sender] + [r for r in others if r != sender]))


MESSAGES = st.one_of(
    st.builds(W.DrLeaderRequest, robot, dest, task, amount),
    st.builds(W.DrBidRequest, robot, dest, task, u32),
    st.builds(W.DrBid, robot, dest, task, u32, amount, amount),
    st.builds(W.DrAward, robot, dest, task, u32, amount),
    st.builds(W.DrRobotAlive, robot, dest, task, u32, amount, u32, amount, amount),
    st.builds(W.DrRefuse, robot, dest, task, u32),
    st.builds(_alive, robot, dest, task, amount, amount, amount, amount, amount, amount, others=members),
    st.builds(W.DrExitLeader, robot, dest, task, st.sampled_from(sorted(W.REASONS))),
    st.builds(W.DrSvrSample, robot, dest, seq, st.floats(0.5, 100, width=32), amount, number),
    st.builds(W.DrSampleRequest, robot, dest, u32),
    st.builds(W.DrLoad, robot, dest, task, seq, amount, amount, u32, amount, amount),
    st.builds(W.DrDeliver, robot, dest, task, seq, amount, u32, amount, amount, amount),
    st.builds(W.DrLedger, robot, dest, task, robot, u32, amount, u32, amount, amount, amount),
)


def test_the_block_holds_one_message_per_wire_class_and_the_fleet_dialect_includes_it(mod):
    ids = {int(m.get("id")): m.get("name") for m in ET.parse(XML).iter("message")}
    assert all(44150 <= i < 44200 for i in ids)
    assert sorted(ids.values()) == sorted(codec.wire_name(c) for c in W.WIRE_MESSAGES)
    assert "<include>dr.xml</include>" in dialect.fleet_xml().read_text()
    codec.check(mod, W.WIRE_MESSAGES)


@settings(max_examples=300, deadline=None)
@given(MESSAGES)
def test_round_trip(mod, msg):
    assert msg.invalid() is None
    got, refused = decode(mod, frame(mod, msg))
    assert refused == 0 and got == [msg]


@pytest.mark.parametrize("msg, why", [
    (W.DrLeaderRequest(3, 0, 5, 0.1), "fleet task id"),                          # origin 0
    (W.DrBid(3, 1, 1 << 16, 1, -0.1, 1.0), "capacity"),
    (W.DrAward(3, 1, 1 << 16, 1, float("nan")), "value"),
    (W.DrLeaderAlive(3, 0, 1 << 16, 1, 1, 1, 1, 1, 1, (4, 5)), "sender"),
    (W.DrLeaderAlive(3, 0, 1 << 16, 1, 1, 1, 1, 1, 1, (3, 3)), "distinct"),
    (W.DrExitLeader(3, 0, 1 << 16, 7), "reason"),
    (W.DrSvrSample(3, 0, 1, 0.0, 1.0, 0.1), "n > 0"),
    (W.DrLoad(3, 1, 1 << 16, 0, 2.0, 0, 0, 0, 0), "seq"),
    (W.DrLedger(3, 0, 1 << 16, 251, 1, 2, 0, 0, 0, 3), "robot"),
])
def test_values_the_protocol_does_not_allow_are_refused_atdecode(mod, msg, why):
    assert why in msg.invalid()
    got, refused = decode(mod, frame(mod, msg))
    assert got == [] and refused == 1


@settings(max_examples=200, deadline=None)
@given(st.lists(MESSAGES, min_size=1, max_size=6), st.randoms(use_true_random=False), st.integers(0, 30))
def test_bit_flipped_and_truncated_frames_never_raise(mod, msgs, rnd, flips):
    got, refused = decode(mod, damage(b"".join(frame(mod, m) for m in msgs), rnd, flips))
    assert len(got) + refused <= len(msgs) + flips
    agent = busy_fleet().robots[1].agent
    for m in got:
        assert isinstance(agent.on_message(m, 30.0), list)


junk = st.one_of(st.integers(-3, 300), st.floats(), st.text(max_size=2), st.none(), st.booleans(),
                 st.lists(st.integers(-2, 300), max_size=10).map(tuple), st.integers(1, 5).map(lambda o: o << 16 | 1))


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(W.WIRE_MESSAGES + (RobotState,)),
                          st.one_of(st.sampled_from([1, 2, 3, 4, 5]), junk),        # mostly from fleet peers
                          st.lists(junk, min_size=11, max_size=11)), max_size=20),
       st.sampled_from([1, 2, 4]))
def test_nonsense_messages_never_raise_and_are_counted(fields, rid):
    agent = busy_fleet().robots[rid].agent
    before = sum(agent.dropped.values())
    bad = 0
    for cls, sender, values in fields:
        names = [f.name for f in dataclasses.fields(cls)]
        m = cls(**dict(zip(names, [sender] + values)))
        bad += (cls is not RobotState and why_invalid(m) is not None) or sender not in (1, 2, 3, 4, 5)
        out = agent.on_message(m, 30.0)
        assert isinstance(out, list) and all(hasattr(o, "dest") for o in out)
        assert isinstance(agent.on_tick(30.05), list)
        assert len(agent.coalitions()) <= 1 and len(agent.commitments) <= 1
    assert sum(agent.dropped.values()) - before >= bad


def _aimed(msg, sender: int, dest: int, task: int):
    """``msg`` from a fleet robot to ``dest`` about one of the busy fleet's tasks (valid, so handlers act on it)."""
    changes = {"sender": sender, "dest": dest}
    if hasattr(msg, "task"):
        changes["task"] = task
    if isinstance(msg, W.DrLeaderAlive):
        changes["members"] = (sender,) + tuple(r for r in msg.members if r not in (sender,) and r <= 5)
    if isinstance(msg, W.DrLedger):
        changes["robot"] = 1 + msg.robot % 5
    return dataclasses.replace(msg, **changes)


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(MESSAGES, st.integers(1, 5), st.sampled_from([0, 1, 2, 3, 4, 5]),
                          st.sampled_from([1 << 16 | 1, 1 << 16 | 2])), max_size=25),
       st.sampled_from([1, 2, 3, 4, 5]))
def test_valid_messages_about_real_tasks_never_raise_and_keep_one_coalition(msgs, rid):
    f = busy_fleet()
    agent = f.robots[rid].agent
    t = 30.0
    for msg, sender, dest, task in msgs:
        if sender == rid:
            continue
        m = _aimed(msg, sender, dest, task)
        assert m.invalid() is None
        out = agent.on_message(m, t)
        out += agent.on_tick(t + 0.05)
        assert all(o.invalid() is None for o in out)
        assert len(agent.coalitions()) <= 1 and len(agent.commitments) <= 1
        t += 0.1
    f.run(f.now + 3.0)                       # the fleet carries on after the poking
    for r in f.robots.values():
        assert len(r.agent.coalitions()) <= 1


def test_foreign_and_misaddressed_messages_are_dropped():
    agent = busy_fleet().robots[2].agent
    before = sum(agent.dropped.values())
    t = 1 << 16 | 1
    agent.on_message(W.DrRefuse(9, 2, t, 1), 30.0)                 # not a configured peer
    agent.on_message(W.DrRefuse(1, 3, t, 1), 30.0)                 # for robot 3
    agent.on_message(("not", "a", "message"), 30.0)
    agent.on_message(W.DrBid(1, 2, t, 1, -1.0, 0.0), 30.0)         # invalid
    assert sum(agent.dropped.values()) - before == 4
    assert {"not a robot of the fleet", "not for me", "not a dr message", "invalid"} <= set(agent.dropped)


def test_random_bytes_decode_to_nothing_or_valid_messages(mod):
    rnd = random.Random(5)
    for _ in range(200):
        data = bytes(rnd.randrange(256) for _ in range(rnd.randrange(1, 300)))
        got, _ = decode(mod, data)
        assert all(m.invalid() is None for m in got)
