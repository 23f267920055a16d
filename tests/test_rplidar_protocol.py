"""RPLIDAR protocol: bytes as Slamtec's SDK and the stock PyPI clients write and read them; hostile streams."""
from __future__ import annotations

import struct

import pytest
from hypothesis import given, settings, strategies as st

from runtime.drivers import rplidar_protocol as P


def accounted(p) -> bool:
    s = p.stats
    return s.bytes == s.good_bytes + s.dropped_bytes + p.pending_bytes


def scan_stream(n: int, first: int = 0, samples: int = 360) -> bytes:
    """``n`` nodes of a scan, step ``first`` on, distance 1000 + step mm."""
    out = bytearray()
    for k in range(first, first + n):
        step = k % samples
        out += P.encode_node(step == 0, 15, step * 64 * 360 // samples, (1000 + step) * 4)
    return bytes(out)


SCAN_DESC = P.descriptor(P.NODE_LEN, P.MODE_MULTIPLE, P.TYPE_SCAN)


# ---------------------------------------------------------------- published bytes

def test_descriptors_are_the_sdks_bytes():
    # rplidar_protocol.h / rplidar_cmd.h: the health descriptor A5 5A 03 00 00 00 06; the scan's length 5, mode 1
    assert P.descriptor(3, 0, P.TYPE_HEALTH) == bytes.fromhex("a55a0300000006")
    assert SCAN_DESC == bytes.fromhex("a55a0500004081")
    assert P.descriptor(20, 0, P.TYPE_INFO) == bytes.fromhex("a55a1400000004")
    assert P.parse_descriptor(SCAN_DESC) == (5, 1, 0x81)
    assert P.parse_descriptor(bytes.fromhex("a55b0500004081")) is None


def test_requests_and_the_pwm_checksum_match_the_stock_client():
    rplidar = pytest.importorskip("rplidar")
    sent = []

    class Port:
        def write(self, data):
            sent.append(bytes(data))

    client = rplidar.RPLidar.__new__(rplidar.RPLidar)
    client._serial_port, client.logger = Port(), rplidar.logging.getLogger("t")
    client.set_pwm(660)
    client._send_cmd(rplidar.SCAN_BYTE)
    assert sent == [P.motor_pwm(660), P.request(P.CMD_SCAN)]
    assert P.motor_pwm(660) == bytes.fromhex("a5f0029402c1")      # XOR of a5 f0 02 94 02
    assert P.request(P.CMD_GET_HEALTH) == b"\xa5\x52"


@given(st.booleans(), st.integers(0, 63), st.integers(0, P.FULL_TURN_Q6 - 1), st.integers(0, 0xFFFF))
@settings(max_examples=60, deadline=None)
def test_nodes_decode_as_the_stock_clients_decode_them(start, quality, angle_q6, dist_q2):
    rplidar = pytest.importorskip("rplidar")
    raw = P.encode_node(start, quality, angle_q6, dist_q2)
    node = P.decode_node(raw)
    assert node == P.Node(start, quality, angle_q6, dist_q2)
    assert rplidar._process_scan(raw) == (start, quality, angle_q6 / 64.0, dist_q2 / 4.0)


def test_info_and_health_round_trip():
    info = P.DeviceInfo(0x18, (1, 29), 7, bytes(range(16)))
    raw = info.encode()
    assert raw[:4] == bytes((0x18, 29, 1, 7)) and P.DeviceInfo.decode(raw) == info and info.name == "A1M8"
    h = P.Health(P.HEALTH_WARNING, 0x1234)
    assert h.encode() == b"\x01\x34\x12" and P.Health.decode(h.encode()) == h


def test_bad_nodes_are_refused():
    good = P.encode_node(True, 15, 64, 4000)
    assert P.decode_node(bytes((good[0] | 0b11,)) + good[1:]) is None       # S and !S both set
    assert P.decode_node(good[:1] + bytes((good[1] & 0xFE,)) + good[2:]) is None   # check bit 0
    assert P.decode_node(good[:1] + struct.pack("<H", P.FULL_TURN_Q6 << 1 | 1) + good[3:]) is None


# ---------------------------------------------------------------- the host's parser

def test_a_session_parses_in_order_in_any_split():
    info = P.DeviceInfo(0x28, (1, 27), 5, bytes(16))
    stream = (P.descriptor(20, 0, 4) + info.encode() + P.descriptor(3, 0, 6) + P.Health(0).encode()
              + SCAN_DESC + scan_stream(400))
    for split in (1, 3, 7, 64, len(stream)):
        p = P.ResponseParser()
        out = []
        for i in range(0, len(stream), split):
            out += p.feed(stream[i:i + split])
        assert out[0] == info and out[1] == P.Health(0) and len(out) == 402
        assert [n.angle_q6 for n in out[2:5]] == [0, 64, 128] and out[2].start and out[362].start
        assert p.stats.dropped_bytes == 0 and accounted(p)


def test_garbage_and_a_mid_frame_start_are_dropped_and_counted():
    p = P.ResponseParser()
    assert p.feed(b"\x00\xff\x13garbage" + SCAN_DESC) == []
    assert p.stats.dropped_bytes == 10 and p.streaming
    body = scan_stream(50)
    out = p.feed(body[2:])                          # joined two bytes into a node
    assert len(out) >= 40 and all(n.distance_q2 == (1000 + n.angle_q6 // 64) * 4 for n in out)
    assert p.stats.dropped_bytes > 10 and p.stats.resyncs >= 1 and accounted(p)
    before = p.stats.nodes
    out = p.feed(b"\x07\x07\x07" + scan_stream(20, 50))      # garbage inside the stream
    assert len(out) >= 15 and p.stats.nodes > before and accounted(p)


def test_a_new_descriptor_ends_the_stream():
    p = P.ResponseParser()
    p.feed(SCAN_DESC + scan_stream(10))
    out = p.feed(P.descriptor(3, 0, 6) + P.Health(2, 5).encode())
    assert out == [P.Health(2, 5)] and not p.streaming and accounted(p)


def _session() -> bytes:
    return (P.descriptor(20, 0, 4) + P.DeviceInfo(0x18, (1, 29), 7, bytes(16)).encode()
            + P.descriptor(3, 0, 6) + P.Health(0).encode() + SCAN_DESC + scan_stream(120))


@given(st.binary(max_size=600), st.integers(1, 64))
@settings(max_examples=80, deadline=None)
def test_random_bytes_never_raise_and_are_accounted(data, split):
    p = P.ResponseParser()
    for i in range(0, len(data), split):
        p.feed(data[i:i + split])
    assert accounted(p) and p.pending_bytes <= max(P.INFO_LEN, P.NODE_LEN * P.LOCK_NODES)


@given(st.integers(0, len(_session())), st.integers(0, len(_session())))
@settings(max_examples=60, deadline=None)
def test_a_truncated_session_never_raises(cut, start):
    p = P.ResponseParser()
    p.feed(_session()[min(start, cut):cut])
    assert accounted(p)


@given(st.lists(st.integers(0, len(_session()) * 8 - 1), min_size=1, max_size=6))
@settings(max_examples=60, deadline=None)
def test_bit_flips_are_counted_and_the_stream_recovers(flips):
    raw = bytearray(_session())
    for bit in flips:
        raw[bit // 8] ^= 1 << (bit % 8)
    p = P.ResponseParser()
    out = p.feed(bytes(raw) + scan_stream(40, 120))
    assert accounted(p)
    assert p.stats.dropped_bytes > 0 or p.stats.nodes + p.stats.frames > 0
    if p.streaming:        # the scan descriptor survived: the tail's clean nodes come through
        assert sum(isinstance(n, P.Node) for n in out) >= 30


# ---------------------------------------------------------------- the device's parser

def test_requests_with_and_without_payload():
    p = P.RequestParser()
    reqs = p.feed(b"zz" + P.request(P.CMD_STOP) + P.motor_pwm(660) + P.request(P.CMD_SCAN))
    assert [r.cmd for r in reqs] == [P.CMD_STOP, P.CMD_MOTOR_PWM, P.CMD_SCAN] and reqs[1].pwm == 660
    assert p.stats.dropped_bytes == 2 and accounted(p)
    bad = bytearray(P.motor_pwm(100))
    bad[-1] ^= 0xFF
    assert p.feed(bytes(bad) + P.request(P.CMD_GET_INFO))[-1].cmd == P.CMD_GET_INFO
    assert p.stats.bad_checksum == 1 and accounted(p)


@given(st.binary(max_size=400), st.integers(1, 32))
@settings(max_examples=80, deadline=None)
def test_device_parser_never_raises_on_random_bytes(data, split):
    p = P.RequestParser()
    for i in range(0, len(data), split):
        p.feed(data[i:i + split])
    assert accounted(p) and p.pending_bytes <= 260
