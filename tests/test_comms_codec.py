"""Agent messages <-> MAVLink: every class round-trips through the codec and the wire."""
from __future__ import annotations

import dataclasses
import math
import struct

import pytest
from hypothesis import given, settings, strategies as st

from runtime.allocation.formation import messages as M
from runtime.comms import codec, dialect
from tests.codec_util import codec_registry_kept


@pytest.fixture(autouse=True)
def _registry_kept():
    with codec_registry_kept():          # tests here register classes of their own
        yield


@pytest.fixture(scope="module")
def mod():
    return dialect.load()


robot = st.integers(1, 250)
dest = st.integers(0, 250)
u16 = st.integers(0, 0xFFFF)
u32 = st.integers(0, 0xFFFFFFFF)
f32 = st.floats(width=32, allow_nan=False)       # float32 values survive the wire exactly

task = st.integers(0, 0xFFFE)                    # valid task ids (0xFFFF: "none", only in Status)
finite = st.floats(width=32, allow_nan=False, allow_infinity=False)
value = st.floats(-M.MAX_VALUE, M.MAX_VALUE, width=32)          # costs, bids, prices: seconds
inf = st.sampled_from([math.inf, -math.inf])
MESSAGES = st.one_of(                            # values the protocol allows (the codec refuses the others)
    st.builds(M.TaskInfo, robot, dest, task, finite, finite, st.integers(1, 0xFFFF), u32),
    st.builds(M.Announce, robot, dest, u32, task, finite, finite, value | inf, u32),
    st.builds(M.Bid, robot, dest, u32, task, value | st.just(math.inf), u32),
    st.builds(M.Award, robot, dest, u32, task, robot, value, value, u32),
    st.builds(M.Price, robot, dest, task, robot, st.floats(0, M.MAX_VALUE, width=32), u16, u32),
    st.builds(M.Status, robot, dest, u32, u16, st.booleans(), u32),
    st.builds(lambda s, d, r, t, rs: M.RoundStart(s, d, r, t, tuple(dict.fromkeys((s, *rs)))), robot, dest, u32,
              st.lists(st.integers(1, 0xFFFFFFFF), min_size=1, max_size=40, unique=True).map(tuple),
              st.lists(robot, max_size=39, unique=True)),
    st.builds(lambda s, d, r, t, rs, last, part: M.RoundStart(s, d, r, t, rs, min(part, last), last),   # one part
              robot, dest, u32, st.lists(st.integers(1, 0xFFFFFFFF), max_size=40, unique=True).map(tuple),
              st.lists(robot, max_size=40, unique=True).map(tuple), st.integers(1, M.MAX_PARTS - 1),
              st.integers(0, M.MAX_PARTS - 1)),
    st.builds(M.RoundLeave, robot, dest, u32),
)


def _wire(mod, msg, key: bytes | None = None):
    """Encode ``msg`` as its sender would, decode it as a peer would."""
    tx = mod.MAVLink(None, srcSystem=msg.sender, srcComponent=1)
    rx = mod.MAVLink(None, srcSystem=200, srcComponent=1)
    if key:
        tx.signing.secret_key = rx.signing.secret_key = key
        tx.signing.sign_outgoing = True
        tx.signing.timestamp = 1
    frame = codec.encode(msg, tx)
    decoded = rx.parse_buffer(frame)
    assert decoded is not None and len(decoded) == 1
    return frame, decoded[0]


def test_every_agent_class_is_registered():
    assert {m.cls for m in codec.mappings()} >= set(M.AGENT_MESSAGES)
    assert codec.wire_name(M.TaskInfo) == "MRTA_TASK_INFO"


@settings(max_examples=300, deadline=None)
@given(MESSAGES)
def test_round_trip_through_the_wire(mod, msg):
    frame, m = _wire(mod, msg)
    assert frame[0] == 0xFD                               # MAVLink 2
    assert m.get_type() == codec.wire_name(type(msg))
    assert m.get_srcSystem() == msg.sender and m.target_system == msg.dest
    back = codec.from_mavlink(m)
    assert back == msg
    assert type(back) is type(msg)
    for f in dataclasses.fields(back):                    # types as declared, bool stays bool
        assert type(getattr(back, f.name)) is type(getattr(msg, f.name))


@settings(max_examples=50, deadline=None)
@given(MESSAGES)
def test_round_trip_signed(mod, msg):
    frame, m = _wire(mod, msg, key=bytes(range(32)))
    assert frame[2] & 0x01 and m.get_signed()
    assert codec.from_mavlink(m) == msg


def test_special_floats_and_none_task(mod):
    a = M.Announce(3, 0, 7, 2, 1.5, -2.25, math.inf)      # reserve +inf: no own cost
    assert codec.from_mavlink(_wire(mod, a)[1]) == a
    offer = M.Announce(3, 0, 8, 2, 1.5, -2.25, -math.inf)  # reserve -inf: for robots holding no task
    assert codec.from_mavlink(_wire(mod, offer)[1]) == offer
    with pytest.raises(codec.InvalidMessage, match="Bid from 3: cost: expected a number, got NaN"):
        codec.from_mavlink(_wire(mod, M.Bid(3, 0, 7, 2, math.nan))[1])     # refused once, at decode
    s = M.Status(4, 0, 0, 0xFFFF, False)
    assert codec.from_mavlink(_wire(mod, s)[1]) == s


@pytest.mark.parametrize("status", [M.Status(4, 9, 1, 3, True), M.Status(4, 9, 0xFFFFFFFF, 0xFFFE, False),
                                    M.Status(4, 0, 0, 0xFFFF, True)])
def test_status_carries_the_auction_it_answers(mod, status):
    _, m = _wire(mod, status)
    assert m.get_type() == "MRTA_STATUS" and m.auction == status.auction and m.target_system == status.dest
    assert codec.from_mavlink(m) == status


def test_doubles_round_to_float32(mod):
    msg = M.Bid(1, 0, 1, 1, 0.1)
    back = codec.from_mavlink(_wire(mod, msg)[1])
    assert back.cost == struct.unpack("<f", struct.pack("<f", 0.1))[0]
    assert back.cost == pytest.approx(0.1, rel=1e-7)


@pytest.mark.parametrize("msg", [M.Bid(1, 0, -1, 1, 1.0), M.Bid(1, 0, 2**32, 1, 1.0),
                                 M.TaskInfo(1, 0, 70000, 0.0, 0.0, 1), M.Award(1, 0, 1, 1, 300, 1.0, 1.0),
                                 M.Status(1, 2, 2**32, 1, False), M.Status(1, 2, -1, 1, False)])
def test_values_outside_the_wire_types_are_refused(mod, msg):
    tx = mod.MAVLink(None, srcSystem=1, srcComponent=1)
    with pytest.raises(ValueError, match=type(msg).__name__):
        codec.encode(msg, tx)


def test_a_round_start_frame_without_its_part_fields_is_one_frame(mod):
    """``part`` and ``last`` are MAVLink 2 extensions: a frame from a sender whose dialect lacks them (its payload
    ends after ``robots``, trailing zeros cut as MAVLink 2 does) decodes as part 0 of last 0, a whole round."""
    msg = M.RoundStart(3, 0, 3 << 16 | 1, (65537, 65538), (3, 4))
    tx = mod.MAVLink(None, srcSystem=3, srcComponent=1)
    frame = bytearray(codec.encode(msg, tx))
    assert frame[1] <= 4 + 160 + 1 + 40                   # zeros cut: no byte of the extensions went out
    assert codec.from_mavlink(mod.MAVLink(None, srcSystem=9, srcComponent=1).parse_buffer(bytes(frame))[0]) == msg


@pytest.mark.parametrize("msg, why", [
    (M.RoundStart(3, 0, 1, (65537,), (3,), 2, 1), "part 2 of last 1"),
    (M.RoundStart(3, 0, 1, (65537,), (3,), 0, M.MAX_PARTS), "part 0 of last 7"),
    (M.RoundStart(3, 0, 1, (65537, 65537), (4,), 0, 1), "tasks"),
    (M.RoundStart(3, 0, 1, (65537,), (4, 4), 1, 1), "robots"),
    (M.RoundStart(3, 0, 1, (), (3,)), "tasks"),                       # a whole round names a task
    (M.RoundStart(3, 0, 1, (65537,), (4,)), "robots"),                # and its sender
])
def test_a_round_start_part_is_refused_for_what_a_part_alone_can_get_wrong(mod, msg, why):
    frame = codec.encode(msg, mod.MAVLink(None, srcSystem=3, srcComponent=1))
    with pytest.raises(codec.InvalidMessage, match=why):
        codec.from_mavlink(mod.MAVLink(None, srcSystem=9, srcComponent=1).parse_buffer(frame)[0])
    assert M.RoundStart(3, 0, 1, (), (4,), 1, 1).invalid() is None     # a later part may name no task, not the sender


def test_non_agent_messages_are_not_decoded(mod):
    mav = mod.MAVLink(None, srcSystem=1, srcComponent=1)
    hb = mav.parse_buffer(mav.heartbeat_encode(10, 8, 0, 0, 3).pack(mav))[0]
    assert codec.from_mavlink(hb) is None and not codec.is_agent(hb)
    with pytest.raises(TypeError):
        codec.to_mavlink(object(), mod)


@dataclasses.dataclass(frozen=True)
class CoalitionBid:                 # the shape issue 3 will add
    sender: int
    dest: int
    auction: int
    tasks: int
    cost: float


def test_a_new_message_needs_only_xml_a_dataclass_and_register(tmp_path):
    text = dialect.XML_PATH.read_text().replace("  </messages>", """\
    <message id="44050" name="MRTA_COALITION_BID">
      <description>test</description>
      <field type="uint8_t" name="target_system">dest</field>
      <field type="uint32_t" name="auction">auction</field>
      <field type="uint32_t" name="tasks">bitmask</field>
      <field type="float" name="cost">cost</field>
    </message>
  </messages>""")
    xml = tmp_path / "mrta.xml"
    xml.write_text(text)
    mod2 = dialect.load(xml)
    codec.register(CoalitionBid)
    try:
        codec.check(mod2, [CoalitionBid])
        msg = CoalitionBid(5, 0, 9, 0b1011, 4.5)
        tx = mod2.MAVLink(None, srcSystem=5, srcComponent=1)
        rx = mod2.MAVLink(None, srcSystem=6, srcComponent=1)
        m = rx.parse_buffer(codec.encode(msg, tx))[0]
        assert m.get_msgId() == 44050 and codec.from_mavlink(m) == msg
    finally:
        codec.unregister(CoalitionBid)
    assert CoalitionBid not in {m.cls for m in codec.mappings()}


def test_check_names_a_field_mismatch(mod):
    @dataclasses.dataclass(frozen=True)
    class Bid:                      # same wire name as the real Bid, one field renamed
        sender: int
        dest: int
        auction: int
        task: int
        price: float

    real = next(m for m in codec.mappings() if m.cls is M.Bid)
    codec.register(Bid)
    try:
        with pytest.raises(ValueError, match="MRTA_BID"):
            codec.check(mod)
    finally:
        codec.unregister(Bid)
        codec.register(real.cls, real.name)
    codec.check(mod)


def test_register_refuses_unsupported_fields():
    @dataclasses.dataclass
    class Bad:
        sender: int
        dest: int
        name: str

    with pytest.raises(TypeError, match="Bad.name"):
        codec.register(Bad)
