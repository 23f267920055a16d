"""The coalition family's wire messages: its block of the dialect, round trips, validation once at decode, and
random, truncated, bit-flipped and nonsense input that never makes the agent raise and is counted."""
from __future__ import annotations

import random
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from hypothesis import given, settings, strategies as st

from runtime.allocation.coalition import wdp_messages as W
from runtime.inprocess import Fleet, kinematic
from runtime.tasks.rendezvous import Rendezvous
from runtime.comms import codec, dialect
from runtime.messages import RobotState, why_invalid

ROOT = Path(__file__).resolve().parents[1]
XML = ROOT / "runtime" / "allocation" / "coalition" / "coalition.xml"


@pytest.fixture(scope="module")
def mod():
    return dialect.load()


robot = st.integers(1, 250)
dest = st.integers(0, 250)
u16 = st.integers(1, 0xFFFF)
u32 = st.integers(0, 0xFFFFFFFF)
f32 = st.floats(width=32, allow_nan=False, allow_infinity=False)
value = st.floats(0, 1e6, width=32)


def coalition(size=8):
    return st.lists(robot, min_size=1, max_size=size, unique=True).map(tuple)


def _with_sender(msgs):
    """Bids and reports name their sender among the robots."""
    def fix(m):
        return m if m.sender in m.robots else type(m)(**{**m.__dict__, "robots": (m.sender,) + m.robots[:7]})
    return msgs.map(fix)


MESSAGES = st.one_of(
    st.builds(W.TaskOffer, robot, dest, u32, u32, f32, f32, u16, f32, coalition(64)),
    _with_sender(st.builds(W.CoalitionBid, robot, dest, u32, u32, coalition(), value)),
    st.builds(W.CoalitionAward, robot, dest, u32, u32, coalition(), f32),
    st.builds(W.AwardAck, robot, dest, u32, u32),
    st.builds(W.AwardCancel, robot, dest, u32, u32),
    _with_sender(st.builds(W.MemberReport, robot, dest, u32, u32, coalition(), st.booleans())),
    st.builds(W.CoalitionDone, robot, dest, u32, u32, coalition()),
)


def _frame(mod, msg) -> bytes:
    return codec.encode(msg, mod.MAVLink(None, srcSystem=msg.sender, srcComponent=1))


def _decode(mod, data: bytes) -> tuple[list, int]:
    """Parse like the link does: (our messages, frames refused)."""
    rx = mod.MAVLink(None, srcSystem=200, srcComponent=1)
    rx.robust_parsing = True
    out, refused = [], 0
    for m in rx.parse_buffer(data) or []:
        try:
            msg = codec.from_mavlink(m)
        except codec.InvalidMessage:
            refused += 1
            continue
        except Exception:                      # a field that will not convert: the link counts it too
            refused += 1
            continue
        if msg is not None:
            out.append(msg)
    return out, refused


def test_the_block_holds_one_message_per_wire_class_and_the_fleet_dialect_includes_it():
    ids = {int(m.get("id")): m.get("name") for m in ET.parse(XML).iter("message")}
    assert all(44050 <= i < 44100 for i in ids)
    assert sorted(ids.values()) == sorted(codec.wire_name(c) for c in W.WIRE_MESSAGES)
    assert "<include>coalition.xml</include>" in dialect.fleet_xml().read_text()


@settings(max_examples=300, deadline=None)
@given(MESSAGES)
def test_round_trip(mod, msg):
    assert msg.invalid() is None
    got, refused = _decode(mod, _frame(mod, msg))
    assert refused == 0 and got == [msg]


@pytest.mark.parametrize("msg, why", [
    (W.CoalitionBid(3, 1, 5, 7, (4, 5), 10.0), "sender 3"),
    (W.CoalitionBid(3, 1, 5, 7, (3, 3), 10.0), "distinct"),
    (W.CoalitionBid(3, 1, 5, 7, (3,), -1.0), ">= 0"),
    (W.MemberReport(3, 1, 5, 7, (1, 2), True), "sender 3"),
    (W.CoalitionAward(1, 3, 5, 7, (2, 251), 1.0), "1..250"),
    (W.TaskOffer(1, 0, 5, 7, float("nan"), 0.0, 1, 0.0, (1, 2)), "finite"),
])
def test_values_the_protocol_does_not_allow_are_refused_at_decode(mod, msg, why):
    assert why in msg.invalid()
    got, refused = _decode(mod, _frame(mod, msg))
    assert got == [] and refused == 1


@settings(max_examples=200, deadline=None)
@given(st.lists(MESSAGES, min_size=1, max_size=6), st.randoms(use_true_random=False), st.integers(0, 30))
def test_bit_flipped_and_truncated_frames_never_raise(mod, msgs, rnd, flips):
    data = bytearray(b"".join(_frame(mod, m) for m in msgs))
    for _ in range(flips):
        i = rnd.randrange(len(data))
        data[i] ^= 1 << rnd.randrange(8)
    data = bytes(data[:rnd.randrange(len(data) + 1)])
    got, refused = _decode(mod, data)
    assert len(got) + refused <= len(msgs) + flips
    agent = _busy_fleet().robots[1].agent
    for m in got:
        assert isinstance(agent.on_message(m, 3.0), list)


_FLEET = None


def _busy_fleet() -> Fleet:
    """Robot 1 auctioneer with coalitions running, robots committed (built once, then copied per use)."""
    global _FLEET
    if _FLEET is None:
        f = kinematic({1: (-3.0, -2.0), 2: (-3.0, 0.0), 3: (3.0, 0.0), 4: (3.0, 2.0)}, "coalition")
        f.run(0.5)
        f.hand_in(1, [Rendezvous(0.0, 0.0, 2, 100.0), Rendezvous(0.0, 2.0, 2, 100.0), Rendezvous(1.0, -2.0, 3, 100.0)])
        f.run(4.0)
        assert f.robots[1].agent.auction.coalitions and f.robots[2].agent.member.job is not None
        _FLEET = f
    return _FLEET


junk = st.one_of(st.integers(-3, 300), st.floats(), st.text(max_size=2), st.none(), st.booleans(),
                 st.lists(st.integers(-2, 300), max_size=10).map(tuple))


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(W.WIRE_MESSAGES + (RobotState,)),
                          st.one_of(st.sampled_from([1, 2, 3, 4]), junk),        # mostly from fleet peers
                          st.lists(junk, min_size=7, max_size=7)), max_size=20),
       st.sampled_from([1, 2, 4]))
def test_nonsense_messages_never_raise_and_are_counted(fields, rid):
    agent = _busy_fleet().robots[rid].agent
    before = agent.dropped
    bad = 0
    for cls, sender, values in fields:
        names = list(cls.__dataclass_fields__)
        m = cls(**dict(zip(names, [sender] + values)))
        bad += (cls is not RobotState and why_invalid(m) is not None) or m.sender not in (1, 2, 3, 4)
        out = agent.on_message(m, 4.0)
        assert isinstance(out, list) and all(hasattr(o, "dest") for o in out)
        assert isinstance(agent.on_tick(4.05), list)
    assert agent.dropped - before >= bad


def test_foreign_and_misaddressed_messages_are_dropped():
    agent = _busy_fleet().robots[2].agent
    before = agent.dropped
    agent.on_message(W.AwardAck(9, 2, 1, 1), 4.0)                   # not a configured peer
    agent.on_message(W.AwardAck(1, 3, 1, 1), 4.0)                   # for robot 3
    agent.on_message(("not", "a", "message"), 4.0)
    assert agent.dropped - before == 3


def test_random_bytes_decode_to_nothing_or_valid_messages(mod):
    rnd = random.Random(5)
    for _ in range(200):
        data = bytes(rnd.randrange(256) for _ in range(rnd.randrange(1, 300)))
        got, _ = _decode(mod, data)
        assert all(m.invalid() is None for m in got)
