"""Counters that add up: every datagram a link or the ground station reads ends in exactly one outcome
(``datagrams == received + dropped``), and datagrams the kernel dropped under a flood are counted too."""
from __future__ import annotations

import socket
import time

import pytest
from hypothesis import given, settings, strategies as st

from runtime.allocation.formation import messages as M
from runtime.comms import codec, dialect, udp
from runtime.comms.gcs import GroundStation
from runtime.comms.link import DROP_REASONS, GCS_LINK, PEER_LINK, MavlinkLink, signing_timestamp
from runtime.messages import RobotState, TaskRecord

KEY = bytes(range(32))
OTHER_KEY = bytes(range(1, 33))
_stamp = [0]


def fresh_stamp() -> int:
    """A signing timestamp after every one used so far and not behind the wall clock (a receiver refuses a new
    stream more than a minute behind its own clock)."""
    _stamp[0] = max(_stamp[0] + 1, signing_timestamp(time.time()))
    return _stamp[0]


def sender(system: int, key=None, link_id=PEER_LINK, stamp=None):
    """A MAVLink encoder for system ``system``, signing with ``key`` on ``link_id`` (None: unsigned)."""
    mav = dialect.load().MAVLink(None, srcSystem=system, srcComponent=1)
    if key is not None:
        mav.signing.secret_key, mav.signing.sign_outgoing, mav.signing.link_id = key, True, link_id
        mav.signing.timestamp = fresh_stamp() if stamp is None else stamp
    return mav


def frame(msg, key=None, link_id=PEER_LINK, stamp=None) -> bytes:
    """``msg`` (one of our dataclasses) as a frame from its sender, signed with ``key`` on ``link_id``."""
    return codec.encode(msg, sender(msg.sender, key, link_id, stamp))


def heartbeat(system: int, key=None, link_id=PEER_LINK) -> bytes:
    mod, mav = dialect.load(), sender(system, key, link_id)
    return mav.heartbeat_encode(mod.MAV_TYPE_GROUND_ROVER, mod.MAV_AUTOPILOT_GENERIC, 0, 0, 4).pack(mav)


def setup_signing(system: int, key=None, link_id=PEER_LINK) -> bytes:
    """A SETUP_SIGNING offering OTHER_KEY, as MAVProxy's `signing setup` sends it."""
    mav = sender(system, key, link_id)
    return mav.setup_signing_encode(1, 1, list(OTHER_KEY), fresh_stamp()).pack(mav)


def reconciles(c) -> bool:
    return c.datagrams == c.received + sum(getattr(c, k) for k in DROP_REASONS) == c.received + c.dropped


@pytest.fixture(scope="module")
def rx():
    links = {"signed": MavlinkLink(1, "127.0.0.1:0", [], signing_key=KEY),
             "plain": MavlinkLink(1, "127.0.0.1:0", [])}
    yield links
    for link in links.values():
        link.close()


robot = st.integers(2, 250)
task = st.integers(0, 0xFFFE)
f32 = st.floats(width=32, allow_nan=False)
MSG = st.one_of(
    st.builds(M.Bid, robot, st.sampled_from([0, 1, 3]), st.integers(0, 2**32 - 1), task, f32),
    st.builds(M.Price, robot, st.just(0), task, robot, st.floats(-10, 10, width=32), st.integers(0, 3)),
    st.builds(RobotState, robot, st.just(0), st.integers(0, 6), st.lists(st.integers(1, 2**24), max_size=3)
              .map(tuple), f32, f32, st.integers(0, 9), st.integers(0, 2**32 - 1)),
)


@st.composite
def datagrams(draw):
    """One datagram of what a hostile network sends: junk, a frame (signed right, wrongly, on the ground-station
    link, or not at all), cut short, bit-flipped, several frames, junk around them."""
    def one():
        kind = draw(st.sampled_from(["junk", "frame", "heartbeat"]))
        if kind == "junk":
            return draw(st.binary(min_size=1, max_size=300))
        key = draw(st.sampled_from([None, KEY, OTHER_KEY]))
        link_id = draw(st.sampled_from([PEER_LINK, GCS_LINK, 7]))
        if kind == "frame":
            data = bytearray(frame(draw(MSG), key, link_id))
        else:
            data = bytearray((heartbeat if kind == "heartbeat" else setup_signing)(draw(st.integers(1, 255)), key,
                                                                                    link_id))
        how = draw(st.sampled_from(["whole", "cut", "flip"]))
        if how == "cut":
            data = data[:draw(st.integers(1, len(data) - 1))]
        elif how == "flip":
            bit = draw(st.integers(0, len(data) * 8 - 1))
            data[bit // 8] ^= 1 << (bit % 8)
        return bytes(data)
    return b"".join(one() for _ in range(draw(st.integers(1, 3))))


@settings(max_examples=400, deadline=None)
@given(datagrams(), st.sampled_from(["signed", "plain"]))
def test_every_datagram_has_exactly_one_outcome(rx, data, which):
    link = rx[which]
    before = link.counters.as_dict()
    out = link.feed(data, 0.0)
    after = link.counters.as_dict()
    moved = {k: after[k] - before[k] for k in ("received",) + DROP_REASONS if after[k] != before[k]}
    assert after["datagrams"] - before["datagrams"] == 1
    assert sum(moved.values()) == 1, moved
    assert link.mav.signing.secret_key == (KEY if which == "signed" else None)      # nothing changes the key
    assert not out or moved == {"received": 1}
    assert reconciles(link.counters)


def test_a_frame_signed_for_the_ground_station_is_dropped_by_a_peer_as_a_replay(rx):
    link = rx["signed"]
    before = link.counters.replayed_dropped
    msg = M.Bid(2, 0, 1, 1, 1.0)
    assert link.feed(frame(msg, KEY, GCS_LINK), 0.0) == []
    assert link.feed(heartbeat(2, KEY, GCS_LINK), 0.0) == []
    assert link.counters.replayed_dropped == before + 2
    assert link.feed(frame(msg, KEY, PEER_LINK), 0.0) == [msg]


def _flood(port: int, n: int, payload: bytes) -> None:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for _ in range(n):
            s.sendto(payload, ("127.0.0.1", port))
    finally:
        s.close()


def _kernel_counts(sock) -> bool:
    return udp.proc_drops(sock) is not None or udp.count_overflows(sock)


def test_datagrams_the_kernel_drops_under_a_flood_are_counted_and_everything_reconciles():
    link = MavlinkLink(1, "127.0.0.1:0", [])
    try:
        if not _kernel_counts(link.sock):
            pytest.skip("this platform does not report a socket's dropped datagrams")
        link.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        n = 3000
        _flood(link.address[1], n, b"\x00junk" * 20)
        for k in range(10):
            link.poll(float(k))                       # 1 s apart: the kernel's count is read once per second
        _flood(link.address[1], 1, b"late")           # carries the count in its ancillary data
        link.poll(10.5)
        c = link.counters
        assert c.kernel_dropped > 0
        assert c.datagrams + c.kernel_dropped == n + 1        # every datagram sent: read or dropped by the kernel
        assert reconciles(c) and c.parse_errors == c.datagrams
    finally:
        link.close()


def test_the_ground_station_counts_every_datagram_once_and_kernel_drops_too():
    gcs = GroundStation(robots={2: ("127.0.0.1", 9)}, signing_key=KEY)
    try:
        port = int(gcs.address.rsplit(":", 1)[1])
        state = RobotState(2, 0, 1, (), 0.0, 0.0, 0, 0)
        sent = [frame(state, KEY, GCS_LINK), frame(state, KEY, PEER_LINK), frame(state), frame(state, OTHER_KEY, GCS_LINK),
                b"\xfd\x01junk", frame(RobotState(9, 0, 1, (), 0.0, 0.0, 0, 0), KEY, GCS_LINK)]
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        for data in sent:
            s.sendto(data, ("127.0.0.1", port))
        s.close()
        t0 = time.monotonic()
        while gcs.counters.datagrams < len(sent) and time.monotonic() - t0 < 2:
            gcs.poll(0.0)
        c = gcs.counters
        assert (c.received, c.replayed_dropped, c.unsigned_dropped, c.bad_signature_dropped, c.parse_errors,
                c.not_for_us) == (1, 1, 1, 1, 1, 1), c.as_dict()
        assert reconciles(c) and gcs.robots[2].state == 1 and 9 not in gcs.robots
        if _kernel_counts(gcs.sock):
            gcs.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            _flood(port, 2000, b"x" * 64)
            for k in range(5):
                gcs.poll(1.0 + k)                     # the kernel's count is read once per second
            assert c.kernel_dropped > 0 and c.datagrams + c.kernel_dropped == len(sent) + 2000
            assert reconciles(c)
    finally:
        gcs.close()


def test_the_ground_station_takes_only_the_fleet_and_values_in_range():
    """Unsigned (a fleet that chose so): frames from a system that is no robot of the fleet are not_for_us; task
    ids no fleet robot minted, holders outside the fleet and values the codec refuses are invalid.  None of them
    changes what the ground station believes, nor raises."""
    gcs = GroundStation(robots={1: ("127.0.0.1", 9), 2: ("127.0.0.1", 9)})
    try:
        good = TaskRecord(2, 255, 2 << 16 | 1, 16, 4, 0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, (2,))
        bad = [RobotState(7, 0, 1, (), 0.0, 0.0, 0, 0),                       # no robot of the fleet
               RobotState(2, 0, 1, (99 << 16 | 1,), 0.0, 0.0, 0, 0),          # a task robot 99 minted
               TaskRecord(2, 255, 99 << 16 | 1, 16, 4, 0, 0, 0, 0, 0, 1.0, 1.0),
               TaskRecord(2, 255, 2 << 16 | 1, 16, 4, 1, 0, 0, 0, 0, 1.0, 1.0, (2, 77)),   # done by robot 77?
               TaskRecord(2, 255, 2 << 16 | 1, 16, 4, 9, 0, 0, 0, 0, 1.0, 1.0),   # state 9
               RobotState(2, 0, 42, (), 0.0, 0.0, 0, 0)]                       # state 42
        port = int(gcs.address.rsplit(":", 1)[1])
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        for msg in [good] + bad:
            s.sendto(frame(msg), ("127.0.0.1", port))
        s.close()
        t0 = time.monotonic()
        while gcs.counters.datagrams < 1 + len(bad) and time.monotonic() - t0 < 2:
            gcs.poll(0.0)
        c = gcs.counters
        assert (c.received, c.not_for_us, c.invalid) == (1, 1, len(bad) - 1), c.as_dict()
        assert gcs.table == {good.task: good} and gcs.status() == {}
        assert reconciles(c)
    finally:
        gcs.close()
