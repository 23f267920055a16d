"""The CoMutaR family's wire messages: its MAVLink block (comutar.xml) matches the dataclasses, messages round
trip through the codec, and random, truncated and bit-flipped frames never raise and are counted."""
from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from hypothesis import given, settings, strategies as st

from runtime.allocation.comutar import messages as M
from runtime.tasks.avoid_obstacles import AvoidObstacles
from runtime.allocation.comutar.options import ComutarOptions
from runtime.allocation.comutar.protocol import ComutarAgent
from runtime.allocation.agent import AgentContext
from runtime.comms import codec, dialect
from runtime.tasks import Profile, Task
from tests.codec_util import codec_registry_kept

XML = Path(__file__).resolve().parents[1] / "runtime" / "allocation" / "comutar" / "comutar.xml"


@pytest.fixture(scope="module")
def mod(tmp_path_factory):
    """The common dialect plus this block (the fleet dialect includes it once the method is registered)."""
    d = tmp_path_factory.mktemp("cm")
    shutil.copy(XML, d / XML.name)
    (d / "top.xml").write_text('<?xml version="1.0"?>\n<mavlink><include>common.xml</include>'
                               f'<include>{XML.name}</include><messages/></mavlink>\n')
    module = dialect.load(d / "top.xml")
    with codec_registry_kept():
        for cls in M.WIRE_MESSAGES:
            codec.register(cls)
        yield module


robot = st.integers(1, 250)
dest = st.integers(0, 250)
u32 = st.integers(1, 0xFFFFFFFF)
fleet_id = st.builds(lambda r, n: r << 16 | n, robot, st.integers(1, 0xFFFF))
f32 = st.floats(0, 1e6, width=32)
xy = st.floats(-1e4, 1e4, width=32)


def refs(first=None, size=M.MAX_SLOTS):
    tail = st.lists(fleet_id, min_size=0 if first is not None else 1, max_size=size - 1, unique=True)
    if first is None:
        return tail.map(tuple)
    return tail.map(lambda t: tuple(dict.fromkeys((first,) + tuple(t))))


def led(s: int, more: tuple) -> tuple:
    """Slot references led by one of the sender's."""
    return tuple(dict.fromkeys((s << 16 | 1,) + more))[:M.MAX_SLOTS]


def _query(s, d, n, *rest):
    return M.CmQuery(s, d, rest[0], s << 16 | n, *rest[1:])


MESSAGES = st.one_of(
    st.builds(M.CmAnnounce, robot, dest, fleet_id, fleet_id, st.floats(0.5, 600, width=32), st.integers(1, 0xFFFF)),
    st.builds(_query, robot, dest, st.integers(1, 0xFFFF), fleet_id, st.integers(1, 255), st.integers(1, 8),
              st.floats(0, 600, width=32), st.floats(0, 600, width=32), robot, xy, xy),
    st.builds(lambda s, d, a, q, c, r, t: M.CmCost(s, d, a, q, c, r, led(s, t)),
              robot, dest, fleet_id, fleet_id, f32, f32, refs(size=47)),
    st.builds(lambda s, d, a, t, c, x: M.CmBid(s, d, a, t, c, led(s, x)), robot, dest, fleet_id, fleet_id, f32,
              refs(size=47)),
    st.builds(M.CmAward, robot, dest, fleet_id, fleet_id, refs()),
    st.builds(M.CmAck, robot, dest, fleet_id, fleet_id),
    st.builds(M.CmResign, robot, dest, fleet_id, fleet_id),
    st.builds(M.CmCancel, robot, dest, fleet_id, fleet_id),
    st.builds(lambda s, d, a, t, x: M.CmHold(s, d, a, t, led(s, x)), robot, dest, fleet_id, fleet_id,
              refs(size=47)),
    st.builds(M.CmDone, robot, dest, fleet_id, fleet_id),
    st.builds(M.CmSurvey, robot, dest, fleet_id, st.integers(0, 200), st.floats(0, 1e6, width=32),
              st.lists(st.integers(1, 200), max_size=200, unique=True).map(tuple)),
    st.builds(M.CmRegion, robot, dest, fleet_id, xy, xy, st.floats(0, 100, width=32)),
    st.builds(lambda s, d, t, i, st_, ox, oy, discs: M.CmStream(s, d, t, i, st_, ox, oy,
                                                                tuple(M.pack_disc(ox + x, oy + y, r, ox, oy) for x, y, r in discs)),
              robot, dest, fleet_id, st.sampled_from([1, 2]), st.floats(0, 1e6, width=32), xy, xy,
              st.lists(st.tuples(st.floats(-30, 30), st.floats(-30, 30), st.floats(0.01, 2.5)), max_size=32)),
)


def _frame(mod, msg) -> bytes:
    return codec.encode(msg, mod.MAVLink(None, srcSystem=msg.sender, srcComponent=1))


def _decode(mod, data: bytes) -> tuple[list, int]:
    rx = mod.MAVLink(None, srcSystem=200, srcComponent=1)
    rx.robust_parsing = True
    out, refused = [], 0
    for m in rx.parse_buffer(data) or []:
        try:
            msg = codec.from_mavlink(m)
        except Exception:                     # InvalidMessage, or a field that will not convert
            refused += 1
            continue
        if msg is not None:
            out.append(msg)
    return out, refused


def test_the_block_holds_one_message_per_wire_class_with_the_same_fields(mod):
    root = ET.parse(XML).getroot()
    names = [m.get("name") for m in root.iter("message")]
    ids = [int(m.get("id")) for m in root.iter("message")]
    assert names == [codec.wire_name(c) for c in M.WIRE_MESSAGES]
    assert all(44200 <= i <= 44249 for i in ids) and len(set(ids)) == len(ids)
    codec.check(mod, M.WIRE_MESSAGES)
    for cls in M.WIRE_MESSAGES:
        size = mod.mavlink_map[getattr(mod, "MAVLINK_MSG_ID_" + codec.wire_name(cls))].unpacker.size
        assert size <= 255


@settings(max_examples=200, deadline=None)
@given(MESSAGES)
def test_every_valid_message_round_trips(mod, msg):
    assert msg.invalid() is None, msg.invalid()
    (back,), refused = _decode(mod, _frame(mod, msg))
    assert refused == 0 and type(back) is type(msg)
    for name in msg.__dataclass_fields__:
        a, b = getattr(msg, name), getattr(back, name)
        assert a == pytest.approx(b, rel=1e-6) if isinstance(a, float) else a == b


@settings(max_examples=200, deadline=None)
@given(st.lists(MESSAGES, min_size=1, max_size=5), st.randoms(use_true_random=False), st.integers(0, 8))
def test_truncated_and_bit_flipped_frames_never_raise_and_what_decodes_is_valid(mod, msgs, rnd, flips):
    data = bytearray(b"".join(_frame(mod, m) for m in msgs))
    for _ in range(flips):
        i = rnd.randrange(len(data))
        data[i] ^= 1 << rnd.randrange(8)
    data = bytes(data[:rnd.randrange(1, len(data) + 1)])
    out, refused = _decode(mod, data)
    assert len(out) <= len(msgs)
    for m in out:
        assert m.invalid() is None
    # whatever decodes, an agent takes it without raising
    agent = ComutarAgent(AgentContext(1, tuple(range(2, 251)), _Est(), ComutarOptions()), ("laser",))
    agent.sense((0, 0, 0))
    agent.add_tasks([Task(1 << 16 | 1, "avoid_obstacles", AvoidObstacles(1))], 0.0)
    for m in out:
        agent.on_message(m, 1.0)
    agent.on_tick(2.0)


class _Est:
    profile = Profile(0.25, 0.25)


@settings(max_examples=100, deadline=None)
@given(st.binary(max_size=600))
def test_random_bytes_never_raise(mod, data):
    out, refused = _decode(mod, data)
    assert all(m.invalid() is None for m in out)


def test_invalid_values_are_refused_at_decode_with_a_reason(mod):
    bad = [
        M.CmAnnounce(1, 0, 5, 1 << 16 | 1, 1.0, 1),                     # auction with no auctioneer id
        M.CmBid(1, 2, 1 << 16 | 1, 1 << 16 | 1, 1.0, (2 << 16 | 1,)),   # a bid whose first slot is not the sender's
        M.CmQuery(1, 0, 1 << 16 | 1, 2 << 16 | 1, 1, 1, 0.5, 1.0, 1, 0.0, 0.0),   # a query id of another robot
        M.CmSurvey(1, 0, 1 << 16 | 1, 0, float("nan"), ()),
        M.CmCost(1, 2, 1 << 16 | 1, 2 << 16 | 1, -1.0, 0.0, (1 << 16 | 1,)),
    ]
    for m in bad:
        assert m.invalid()
        raw = mod.MAVLink(None, srcSystem=m.sender, srcComponent=1)
        frame = codec.to_mavlink(m, mod).pack(raw)
        out, refused = _decode(mod, frame)
        assert out == [] and refused == 1, m
