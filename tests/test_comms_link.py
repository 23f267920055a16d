"""MavlinkLink on loopback: exchange, addressing, signing, liveness, and a parser that never raises."""
from __future__ import annotations

import time

import pytest
from hypothesis import given, settings, strategies as st

from runtime.allocation.formation import messages as M
from runtime.comms import codec, dialect
from runtime.comms.link import DROP_REASONS, LinkCounters, MavlinkLink, load_key, parse_address, signing_timestamp
from runtime.errors import InputError

KEY = bytes(range(32))
OTHER_KEY = bytes(range(1, 33))
DROPS = DROP_REASONS


@pytest.fixture
def links():
    made = []

    def make(robot_id, peers=(), key=None, **kw):
        link = MavlinkLink(robot_id, "127.0.0.1:0", [f"127.0.0.1:{p.address[1]}" for p in peers],
                           None, signing_key=key, **kw)
        made.append(link)
        return link

    yield make
    for link in made:
        link.close()


def pump(link, now, done, limit=2.0) -> list:
    """Poll until ``done(messages so far)`` (loopback delivery is near-immediate); return the messages."""
    got, t0 = [], time.monotonic()
    while True:
        got += link.poll(now)
        if done(got) or time.monotonic() - t0 > limit:
            return got
        time.sleep(0.001)


def drain(link, now, want=1):
    return pump(link, now, lambda got: len(got) >= want)


def settle(link, now, attr, value) -> int:
    pump(link, now, lambda got: getattr(link.counters, attr) >= value)
    return getattr(link.counters, attr)


ALL = [M.TaskInfo(2, 0, 3, 1.5, -2.0, 4), M.Announce(2, 0, 11, 3, 1.5, -2.0, float("inf")),
       M.Bid(2, 0, 11, 3, 0.75), M.Award(2, 0, 11, 3, 1, 0.75, 1.25), M.Price(2, 0, 3, 1, 0.5, 2),
       M.Status(2, 0, 11, 3, True)]


# ---------------------------------------------------------------------------------------- exchange

def test_two_links_exchange_every_agent_message(links):
    a = links(1)
    b = links(2, peers=[a])
    b.send_agent(ALL, 0.0)
    got = drain(a, 0.0, want=len(ALL))
    assert got == ALL
    assert a.counters.agent_received == len(ALL) and b.counters.sent == len(ALL)


def test_peer_loss_drops_its_share_of_each_peers_copies_and_counts_them(links):
    a, c = links(1), links(3)
    b = links(2, peers=[a, c], peer_loss=0.25, loss_seed=7)
    msgs = [M.Bid(2, 0, 1, k, float(k)) for k in range(200)]     # each receiver's socket holds them all
    b.send_agent(msgs, 0.0)
    n = b.counters
    assert n.loss_injected + n.peer_sent == 400 and n.sent == n.peer_sent and 60 < n.loss_injected < 140
    got_a = pump(a, 0.0, lambda got: False, limit=0.3)
    got_c = pump(c, 0.0, lambda got: False, limit=0.3)
    assert len(got_a) + len(got_c) == n.peer_sent
    assert {m.task for m in got_a} != {m.task for m in got_c}      # each receiver misses its own copies
    none, every = links(5, peers=[a], peer_loss=1.0), links(6, peers=[a])
    none.send_agent(msgs[:10], 0.0)
    every.send_agent(msgs[:10], 0.0)
    assert none.counters.peer_sent == 0 and none.counters.loss_injected == 10 and every.counters.peer_sent == 10
    with pytest.raises(InputError, match="comms.peer_loss"):
        links(7, peer_loss=1.5)


def test_loss_in_bursts_keeps_the_share_and_loses_runs_of_copies(links):
    a = links(1)
    b = links(2, peers=[a], peer_loss=0.2, loss_burst=1.0, loss_seed=3)
    lost = []
    for k in range(20_000):                               # a copy every 0.1 s for 2000 s, no socket needed
        lost.append(b.peer_loss and b._loses(a.address, 0.1 * k))
    share = sum(lost) / len(lost)
    runs = [len(r) for r in "".join("x" if x else "." for x in lost).split(".") if r]
    assert 0.15 < share < 0.25                            # the share asked for
    assert 6 < sum(runs) / len(runs) < 14                 # spells of a mean 1 s: about 10 copies in a row
    b.send_agent([M.Bid(2, 0, 1, 1, 1.0)], 0.0)           # the send path goes through it
    assert b.counters.loss_injected + b.counters.peer_sent == 1
    with pytest.raises(InputError, match="comms.loss_burst"):
        links(3, peer_loss=0.1, loss_burst=-1.0)


def test_addressing_and_own_echo(links):
    a = links(1)
    b = links(2, peers=[a])
    b.send_agent([M.Bid(2, 1, 1, 1, 1.0), M.Bid(2, 3, 1, 1, 2.0), M.Bid(2, 0, 1, 1, 3.0)], 0.0)
    got = drain(a, 0.0, want=2)
    assert [m.cost for m in got] == [1.0, 3.0]             # dest 1 and broadcast; dest 3 is not ours
    assert a.counters.not_for_us == 1
    echo = links(1, peers=[a])                             # a frame claiming our own id
    echo.send_agent([M.Bid(1, 0, 1, 1, 4.0)], 0.0)
    assert settle(a, 0.0, "not_for_us", 2) == 2


def test_sender_on_the_wire_is_the_link_id(links):
    a = links(1)
    b = links(7, peers=[a])
    b.send_agent([M.Bid(99, 0, 1, 1, 1.0)], 0.0)
    assert drain(a, 0.0)[0].sender == 7


def test_bad_values_are_counted_not_sent(links):
    a = links(1)
    b = links(2, peers=[a])
    b.send_agent([M.Bid(2, 0, -5, 1, 1.0), M.Bid(2, 0, 5, 1, 1.0)], 0.0)
    assert b.counters.encode_errors == 1 and b.counters.sent == 1
    assert drain(a, 0.0)[0].auction == 5


# ---------------------------------------------------------------------------------------- signing

def test_signing_drops_unsigned_and_wrong_key_senders(links):
    a = links(1, key=KEY)
    good = links(2, peers=[a], key=KEY)
    unsigned = links(3, peers=[a])
    wrong = links(4, peers=[a], key=OTHER_KEY)
    for s in (unsigned, wrong, good):
        s.send_agent([M.Bid(s.robot_id, 0, 1, 1, float(s.robot_id))], 0.0)
    c = a.counters
    got = pump(a, 0.0, lambda got: got and c.unsigned_dropped and c.bad_signature_dropped)
    assert [m.sender for m in got] == [2]
    assert a.counters.unsigned_dropped == 1
    assert a.counters.bad_signature_dropped == 1
    assert a.counters.agent_received == 1


def test_signed_frames_carry_link_id_zero_and_a_current_timestamp(links):
    fixed = 1_700_000_000.0
    a = links(1)
    b = links(2, peers=[a], key=KEY, wallclock=lambda: fixed)
    b.send_agent([M.Bid(2, 0, 1, 1, 1.0)], 0.0)
    data = None
    t0 = time.monotonic()
    while data is None and time.monotonic() - t0 < 2:
        try:
            data, _ = a.sock.recvfrom(65535)
        except BlockingIOError:
            time.sleep(0.001)
    assert data[2] & 0x01                                  # signed
    link_id = data[-13]
    stamp = int.from_bytes(data[-12:-6], "little")
    assert link_id == 0
    assert stamp == signing_timestamp(fixed) == int((fixed - 1420070400) * 100_000)


def test_forged_frame_does_not_block_the_genuine_sender(links):
    a = links(1, key=KEY)
    good = links(2, peers=[a], key=KEY)
    forger = links(2, peers=[a], key=OTHER_KEY, wallclock=lambda: time.time() + 30)  # same id, later stamps
    forger.send_agent([M.Bid(2, 0, 1, 1, 66.0)], 0.0)
    settle(a, 0.0, "bad_signature_dropped", 1)
    good.send_agent([M.Bid(2, 0, 1, 1, 1.0)], 0.0)
    got = drain(a, 0.0)
    assert [m.cost for m in got] == [1.0]
    assert a.counters.bad_signature_dropped == 1


def test_replayed_frame_is_dropped(links):
    a = links(1, key=KEY)
    b = links(2, peers=[a], key=KEY)
    b.send_agent([M.Bid(2, 0, 1, 1, 1.0)], 0.0)
    frame = None
    t0 = time.monotonic()
    while frame is None and time.monotonic() - t0 < 2:
        try:
            frame, _ = a.sock.recvfrom(65535)
        except BlockingIOError:
            time.sleep(0.001)
    assert len(a.feed(frame, 0.0)) == 1
    assert a.feed(frame, 0.0) == []
    assert a.counters.bad_signature_dropped == 1


def test_unsigned_gcs_heartbeat_is_accepted_but_is_no_peer(links):
    a = links(1, key=KEY)
    mod = dialect.load()
    gcs = mod.MAVLink(None, srcSystem=255, srcComponent=190)
    rover = mod.MAVLink(None, srcSystem=9, srcComponent=1)
    a.feed(gcs.heartbeat_encode(mod.MAV_TYPE_GCS, mod.MAV_AUTOPILOT_INVALID, 0, 0, 4).pack(gcs), 5.0)
    a.feed(rover.heartbeat_encode(mod.MAV_TYPE_GROUND_ROVER, mod.MAV_AUTOPILOT_GENERIC, 0, 0, 4)
           .pack(rover), 5.0)
    assert a.gcs_last_heartbeat == 5.0
    assert a.counters.unsigned_dropped == 1
    a.poll(5.0)
    assert a.peers_alive == []


def test_load_key(tmp_path):
    p = tmp_path / "fleet.key"
    p.write_text(KEY.hex() + "\n")
    assert load_key(p) == KEY
    for text, why in [(KEY.hex()[:-1], "63 characters"), ("zz" * 32, "non-hex"), ("", "0 characters")]:
        p.write_text(text)
        with pytest.raises(InputError, match=why) as e:
            load_key(p)
        assert str(p) in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(InputError, match="not found"):
        load_key(tmp_path / "missing.key")
    p.write_bytes(b"\xff" * 64)
    with pytest.raises(InputError, match="non-ASCII"):
        load_key(p)


@pytest.mark.parametrize("text, what", [("127.0.0.1", "host:port"), ("127.0.0.1:x", "numeric"),
                                        ("127.0.0.1:70000", "port"), (":14550", "host:port")])
def test_bad_addresses_name_the_key(text, what):
    with pytest.raises(InputError, match=what) as e:
        parse_address(text, "comms.gcs")
    assert str(e.value).startswith("comms.gcs:")


def test_multicast_and_broadcast_peers_are_refused():
    for addr in ("224.0.0.1:14550", "255.255.255.255:14550"):
        with pytest.raises(InputError, match="unicast"):
            MavlinkLink(1, "127.0.0.1:0", [addr])


def test_listen_port_in_use(links):
    a = links(1)
    with pytest.raises(InputError, match="cannot bind"):
        MavlinkLink(2, f"127.0.0.1:{a.address[1]}", [])


# ---------------------------------------------------------------------------------------- liveness

def test_heartbeats_once_per_period(links):
    a = links(1)
    b = links(2, peers=[a])
    for t in (0.0, 0.3, 0.6, 0.9):
        b.poll(t)
    assert settle(a, 0.0, "heartbeats", 1) == 1
    b.poll(1.0)
    assert settle(a, 1.0, "heartbeats", 2) == 2


def test_peer_loss_after_heartbeat_timeout_with_injected_clock(links):
    a = links(1, heartbeat_timeout=3.0)
    b = links(2, peers=[a])
    b.poll(0.0)                                            # b heartbeats
    settle(a, 0.0, "heartbeats", 1)
    assert a.peers_alive == [2]
    b.close()                                              # b goes silent
    assert a.peers_lost(2.0) == [] and a.peers_lost(3.0) == []
    a.poll(3.01)
    assert a.peers_alive == []
    assert a.peers_lost(3.01) == [2]
    assert a.peers_lost(10.0) == []                        # reported once
    b2 = links(2, peers=[a])                               # b comes back
    b2.poll(20.0)
    settle(a, 20.0, "heartbeats", 2)
    assert a.peers_alive == [2]
    assert a.peers_lost(23.0) == [] and a.peers_lost(23.5) == [2]


def test_signed_fleet_ignores_unsigned_and_wrongly_signed_heartbeats(links):
    a = links(1, key=KEY)
    stranger = links(3, peers=[a])
    stranger.poll(0.0)
    settle(a, 0.0, "unsigned_dropped", 1)
    assert a.peers_alive == []
    impostor = links(4, peers=[a], key=OTHER_KEY)
    impostor.poll(0.0)
    settle(a, 0.0, "bad_signature_dropped", 1)
    assert a.peers_alive == [] and a.counters.heartbeats == 0
    friend = links(2, peers=[a], key=KEY)
    friend.poll(0.0)
    settle(a, 0.0, "heartbeats", 1)
    assert a.peers_alive == [2]


# ---------------------------------------------------------------------------------------- parser

@pytest.fixture(scope="module")
def rx_plain():
    link = MavlinkLink(1, "127.0.0.1:0", [])
    yield link
    link.close()


@pytest.fixture(scope="module")
def rx_signed():
    link = MavlinkLink(1, "127.0.0.1:0", [], signing_key=KEY)
    yield link
    link.close()


robot = st.integers(2, 250)
u16 = st.integers(0, 0xFFFF)
task = st.integers(0, 0xFFFE)                              # valid task ids (0xFFFF means "none")
finite = st.floats(width=32, allow_nan=False, allow_infinity=False)
value = st.floats(-M.MAX_VALUE, M.MAX_VALUE, width=32)    # costs and prices the protocol carries
AGENT = st.one_of(                                         # messages the protocol allows (invalid ones: below)
    st.builds(M.TaskInfo, robot, st.just(0), task, finite, finite, st.integers(1, 0xFFFF)),
    st.builds(M.Bid, robot, st.just(1), st.integers(0, 2**32 - 1), task, value | st.just(float("inf"))),
    st.builds(M.Award, robot, st.just(0), st.integers(0, 2**32 - 1), task, robot, value, value),
    st.builds(M.Status, robot, st.just(1), st.integers(0, 2**32 - 1), u16, st.booleans()),
)
_stamp = [signing_timestamp(time.time())]


def frame_of(msg, key=None) -> bytes:
    mod = dialect.load()
    mav = mod.MAVLink(None, srcSystem=msg.sender, srcComponent=1)
    if key:
        mav.signing.secret_key, mav.signing.sign_outgoing = key, True
        _stamp[0] += 1                                     # fresh stamp: never a replay
        mav.signing.timestamp = _stamp[0]
    return codec.encode(msg, mav)


def snapshot(link) -> dict:
    return link.counters.as_dict()


def dropped(before, after) -> int:
    return sum(after[k] - before[k] for k in DROPS)


def after_parse_errors(link, before) -> int:
    return link.counters.parse_errors - before["parse_errors"]


FUZZ = settings(max_examples=300, deadline=None)


@FUZZ
@given(st.binary(min_size=1, max_size=600))
def test_random_datagrams_never_raise_and_are_counted(rx_plain, data):
    before = snapshot(rx_plain)
    out = rx_plain.feed(data, 0.0)
    after = snapshot(rx_plain)
    assert after["datagrams"] == before["datagrams"] + 1
    accepted = after["received"] - before["received"]
    assert accepted + dropped(before, after) == 1            # one outcome per datagram
    assert not out or accepted == 1


@FUZZ
@given(AGENT, st.data())
def test_truncated_frames_are_counted_never_delivered(rx_plain, msg, data):
    frame = frame_of(msg)
    cut = data.draw(st.integers(1, len(frame) - 1))
    before = snapshot(rx_plain)
    assert rx_plain.feed(frame[:cut], 0.0) == []
    assert after_parse_errors(rx_plain, before) >= 1



@FUZZ
@given(AGENT, st.data())
def test_bit_flipped_signed_frames_are_counted_never_delivered(rx_signed, msg, data):
    frame = bytearray(frame_of(msg, KEY))
    bit = data.draw(st.integers(0, len(frame) * 8 - 1))
    frame[bit // 8] ^= 1 << (bit % 8)
    before = snapshot(rx_signed)
    assert rx_signed.feed(bytes(frame), 0.0) == []
    assert dropped(before, snapshot(rx_signed)) >= 1


@FUZZ
@given(AGENT, st.data())
def test_bit_flipped_unsigned_frames_are_counted_never_delivered(rx_plain, msg, data):
    frame = bytearray(frame_of(msg))
    bit = data.draw(st.integers(0, len(frame) * 8 - 1))
    frame[bit // 8] ^= 1 << (bit % 8)
    before = snapshot(rx_plain)
    assert rx_plain.feed(bytes(frame), 0.0) == []          # CRC-16 catches every single-bit error
    assert dropped(before, snapshot(rx_plain)) >= 1


@FUZZ
@given(st.binary(min_size=1, max_size=50).filter(lambda b: 0xFD not in b and 0xFE not in b), AGENT)
def test_junk_before_a_frame_is_counted_and_the_frame_survives(rx_plain, junk, msg):
    before = snapshot(rx_plain)
    assert rx_plain.feed(junk + frame_of(msg), 0.0) == [msg]
    after = snapshot(rx_plain)
    assert after["received"] - before["received"] == 1      # the datagram gave a frame: received ...
    assert after["frames_dropped"] - before["frames_dropped"] == 1     # ... and its junk is counted as a frame


def test_frames_of_one_datagram_all_arrive_and_partial_state_does_not_leak(rx_plain):
    msgs = [M.Bid(2, 0, i, 1, float(i)) for i in range(5)]
    assert rx_plain.feed(b"".join(frame_of(m) for m in msgs), 0.0) == msgs
    whole = frame_of(msgs[0])
    assert rx_plain.feed(whole[:7], 0.0) == []              # cut short ...
    assert rx_plain.feed(whole, 0.0) == [msgs[0]]           # ... and the next datagram is clean


def test_counters_are_plain_numbers():
    c = LinkCounters()
    assert set(c.as_dict()) >= {"received", "bad_crc", "parse_errors", "unsigned_dropped",
                                "bad_signature_dropped", "not_for_us"}


def test_values_the_protocol_does_not_allow_are_dropped_once_at_decode_and_counted(links):
    """Validation happens in the codec: a handler never sees a Price held by robot 0, a NaN bid, a round
    naming a robot twice, or a task record with an infinite position."""
    from runtime.messages import TaskRecord
    a = links(1)
    b = links(2, peers=[a])
    bad = [M.Price(2, 0, 3, 0, 0.5, 2), M.Bid(2, 0, 11, 3, float("nan")),
           M.RoundStart(2, 0, 7, (65537,), (2, 2)), TaskRecord(2, 0, 65537, 16, 4, 0, 0, 0, 0, 0, float("inf"), 0.0)]
    good = M.Bid(2, 0, 11, 3, 0.75)
    b.send_agent(bad + [good], 0.0)
    assert drain(a, 0.0) == [good]
    assert settle(a, 0.0, "invalid", len(bad)) == len(bad)


def test_mrta_key_makes_a_0600_key_the_link_loads_and_never_overwrites(tmp_path, capsys):
    import os
    import stat

    from runtime.cli import main
    path = tmp_path / "fleet.key"
    assert main(["key", str(path)]) == 0
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
    assert len(load_key(path)) == 32
    assert not [p for p in tmp_path.iterdir() if p.name != "fleet.key"]      # no temporary file left
    before = path.read_bytes()
    assert main(["key", str(path)]) == 2                                       # refuses to replace a key
    assert path.read_bytes() == before
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and str(path) in err and "never overwritten" in err


def test_mrta_key_from_a_passphrase_is_the_key_mavproxy_derives_in_the_same_file_format(tmp_path, capsys):
    """MAVProxy's `signing key P` signs with hashlib.sha256(P.encode('ascii')).digest()
    (MAVProxy/modules/mavproxy_signing.py, passphrase_to_key); `mrta key FILE --passphrase P` writes that key as
    `mrta key FILE` writes a fresh one: 64 hex characters and a newline, mode 0600."""
    import hashlib
    import os
    import stat

    from runtime.cli import main
    path = tmp_path / "fleet.key"
    assert main(["key", str(path), "--passphrase", "Rover-fleet_42!"]) == 0
    assert load_key(path) == hashlib.sha256("Rover-fleet_42!".encode("utf-8")).digest()
    assert path.read_text() == hashlib.sha256(b"Rover-fleet_42!").hexdigest() + "\n"
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
    fresh = tmp_path / "fresh.key"
    assert main(["key", str(fresh)]) == 0
    assert len(fresh.read_text()) == len(path.read_text()) and load_key(fresh) != load_key(path)
    capsys.readouterr()


@pytest.mark.parametrize("passphrase, expected", [
    ("", "--passphrase: expected a passphrase, got an empty one"),
    ("two words", "--passphrase: expected printable ASCII without spaces, quotes or ';'"),
    ("clé", "--passphrase: expected printable ASCII without spaces, quotes or ';'"),
    ('say"hi', "--passphrase: expected printable ASCII without spaces, quotes or ';'"),
    ("a;b", "--passphrase: expected printable ASCII without spaces, quotes or ';'"),
])
def test_a_passphrase_mavproxy_cannot_take_as_typed_is_refused_with_one_line_and_no_file(tmp_path, capsys,
                                                                                         passphrase, expected):
    from runtime.cli import main
    path = tmp_path / "fleet.key"
    assert main(["key", str(path), "--passphrase", passphrase]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"mrta: {expected}") and err.count("\n") == 1, err
    assert not list(tmp_path.iterdir())


# ---------------------------------------------------------------------------------------- SETUP_SIGNING

def setup_signing(new_key: bytes, key=None, system=255, component=190, link_id=0) -> bytes:
    """MAVProxy's `signing setup P` as it goes on the wire: SETUP_SIGNING with the new key, signed with ``key`` (the
    key the ground station has already, `signing key P` before) or unsigned."""
    mod = dialect.load()
    mav = mod.MAVLink(None, srcSystem=system, srcComponent=component)
    if key is not None:
        mav.signing.secret_key, mav.signing.sign_outgoing, mav.signing.link_id = key, True, link_id
        mav.signing.timestamp = signing_timestamp(time.time())
    return mav.setup_signing_encode(1, 1, list(new_key), signing_timestamp(time.time())).pack(mav)


class Station:
    """A UDP socket on loopback that sends raw frames to a link and reads what comes back (parsed with ``key``)."""

    def __init__(self, key=None):
        import socket
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.rx = dialect.load().MAVLink(None)
        if key is not None:
            self.rx.signing.secret_key = key

    def texts(self, limit=0.3) -> list:
        """The STATUSTEXTs that arrive within ``limit`` s (loopback: at once), as (text, link id of the frame)."""
        out, t0 = [], time.monotonic()
        while time.monotonic() - t0 < limit:
            try:
                data, _ = self.sock.recvfrom(65535)
            except BlockingIOError:
                time.sleep(0.002)
                continue
            for m in self.rx.parse_buffer(data) or []:
                if m.get_type() == "STATUSTEXT":
                    out.append((m.text, data[-13] if data[2] & 1 else None))
        return out

    def close(self):
        self.sock.close()


@pytest.fixture
def station():
    made = []

    def make(key=None):
        made.append(Station(key))
        return made[-1]

    yield make
    for s in made:
        s.close()


def reconciles(c) -> bool:
    return c.datagrams == c.received + c.dropped


@pytest.mark.parametrize("sent_with", [KEY, None], ids=["signed-with-the-fleet-key", "unsigned"])
def test_setup_signing_is_refused_counted_and_answered_once_and_the_key_stays(links, station, sent_with):
    from runtime.comms.link import GCS_LINK, KEY_REFUSAL_PERIOD, KEY_REFUSAL_TEXT
    a = links(1, key=KEY)
    peer = links(2, peers=[a], key=KEY)
    gcs = station(KEY)
    for k in range(3):                                   # MAVProxy's `signing setup P`, typed three times
        gcs.sock.sendto(setup_signing(OTHER_KEY, sent_with), a.address)
    settle(a, 1.0, "setup_signing_refused", 3)
    assert a.counters.setup_signing_refused == 3 and a.counters.received == 0 and reconciles(a.counters)
    assert gcs.texts() == [(KEY_REFUSAL_TEXT, GCS_LINK)] and a.counters.setup_signing_replies == 1
    assert len(KEY_REFUSAL_TEXT) <= 50                   # one STATUSTEXT, no chunks
    assert a.mav.signing.secret_key == KEY
    peer.send_agent([M.Bid(2, 0, 1, 1, 1.0)], 2.0)       # the fleet key still works, the offered one does not
    assert [m.cost for m in drain(a, 2.0)] == [1.0]
    rogue = links(2, peers=[a], key=OTHER_KEY)
    rogue.send_agent([M.Bid(2, 0, 1, 1, 9.0)], 2.0)
    assert settle(a, 2.0, "bad_signature_dropped", 1) == 1
    gcs.sock.sendto(setup_signing(OTHER_KEY, sent_with), a.address)      # a period later: told again
    settle(a, 1.0 + KEY_REFUSAL_PERIOD, "setup_signing_refused", 4)
    assert gcs.texts() == [(KEY_REFUSAL_TEXT, GCS_LINK)] and a.counters.setup_signing_replies == 2


def test_an_unsigned_robot_takes_no_key_either_and_a_peer_is_told_on_the_peer_link(links, station):
    from runtime.comms.link import KEY_REFUSAL_TEXT, PEER_LINK
    a = links(1)
    peer = station()
    peer.sock.sendto(setup_signing(KEY, system=2, component=1), a.address)
    settle(a, 0.0, "setup_signing_refused", 1)
    assert not a.signing and a.mav.signing.secret_key is None
    assert peer.texts() == [(KEY_REFUSAL_TEXT, None)]            # an unsigned robot's answer is unsigned
    b = links(3, key=KEY)
    peer.rx.signing.secret_key = KEY
    peer.sock.sendto(setup_signing(OTHER_KEY, KEY, system=2, component=1), b.address)
    settle(b, 0.0, "setup_signing_refused", 1)
    assert peer.texts() == [(KEY_REFUSAL_TEXT, PEER_LINK)]


def test_a_wrongly_signed_setup_signing_is_a_bad_signature_and_gets_no_answer(links, station):
    a = links(1, key=KEY)
    gcs = station()
    gcs.sock.sendto(setup_signing(OTHER_KEY, OTHER_KEY), a.address)
    settle(a, 0.0, "bad_signature_dropped", 1)
    assert a.counters.setup_signing_refused == 0 and gcs.texts() == [] and a.mav.signing.secret_key == KEY


def test_refusals_cannot_be_used_to_flood_many_addresses(links):
    """Every SETUP_SIGNING is counted, but answers go to at most MAX_KEY_REFUSAL_SENDERS addresses per period,
    whatever source addresses a flood claims."""
    from runtime.comms.link import KEY_REFUSAL_PERIOD, MAX_KEY_REFUSAL_SENDERS
    a = links(1, key=KEY)
    sink = links(9)                                           # where the answers land (all claimed addresses)
    frame = setup_signing(OTHER_KEY)
    n = MAX_KEY_REFUSAL_SENDERS + 20
    for k in range(n):
        a.feed(frame, 5.0, ("127.0.0.1", sink.address[1] if k == 0 else 40000 + k))
    assert a.counters.setup_signing_refused == n
    assert a.counters.setup_signing_replies == MAX_KEY_REFUSAL_SENDERS
    a.feed(frame, 5.0 + KEY_REFUSAL_PERIOD, ("127.0.0.1", 40000 + n))     # a period on, the table has room again
    assert a.counters.setup_signing_replies == MAX_KEY_REFUSAL_SENDERS + 1
