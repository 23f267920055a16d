"""The socketcand hub with python-can's stock socketcand client: handshake, frames both ways, several clients,
and garbage on the socket that is counted while the hub goes on serving."""
from __future__ import annotations

import socket
import time

import can
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from sitl import can_hub
from sitl.can_hub import CanHub


def client(hub: CanHub, channel: str = "can1") -> can.BusABC:
    return can.Bus(interface="socketcand", host=hub.host, port=hub.port, channel=channel)


def recv_until(bus, pred, timeout=2.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        msg = bus.recv(0.05)
        if msg is not None and pred(msg):
            return msg
    return None


@pytest.fixture
def hub():
    h = CanHub()
    yield h
    h.close()


def frame(can_id, data):
    return can.Message(arbitration_id=can_id, data=bytes(data), is_extended_id=can_id > 0x7FF)


def test_stock_client_frames_reach_the_virtual_side_and_other_clients_not_the_sender(hub):
    drive = can.Bus(interface="virtual", channel=hub.add_channel("can1"))
    a, b = client(hub), client(hub)
    try:
        a.send(frame(0x601, [0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0]))
        got = drive.recv(2.0)
        assert (got.arbitration_id, bytes(got.data)) == (0x601, bytes([0x40, 0, 0x10, 0, 0, 0, 0, 0]))
        assert recv_until(b, lambda m: m.arbitration_id == 0x601) is not None
        drive.send(frame(0x581, [0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00]))
        hub.pump("can1")
        for bus in (a, b):
            got = recv_until(bus, lambda m: m.arbitration_id == 0x581)
            assert got is not None and bytes(got.data) == bytes([0x43, 0, 0x10, 0, 0x92, 1, 2, 0])
        assert recv_until(a, lambda m: m.arbitration_id == 0x601, timeout=0.3) is None      # no echo
        ext = frame(0x18FF50E5, [1, 2, 3])
        a.send(ext)
        got = drive.recv(2.0)
        assert got.is_extended_id and got.arbitration_id == 0x18FF50E5 and bytes(got.data) == b"\x01\x02\x03"
    finally:
        a.shutdown()
        b.shutdown()
        drive.shutdown()
    assert hub.stats.clients == 2 and hub.stats.bad_commands == 0


def test_channels_are_separate(hub):
    d1 = can.Bus(interface="virtual", channel=hub.add_channel("can1"))
    d2 = can.Bus(interface="virtual", channel=hub.add_channel("can2"))
    c2 = client(hub, "can2")
    try:
        d1.send(frame(0x701, [5]))
        d2.send(frame(0x702, [5]))
        hub.pump()
        got = recv_until(c2, lambda m: True)
        assert got.arbitration_id == 0x702
        assert recv_until(c2, lambda m: m.arbitration_id == 0x701, timeout=0.3) is None
    finally:
        c2.shutdown()
        d1.shutdown()
        d2.shutdown()


def test_an_unknown_channel_fails_the_stock_client_with_a_can_error(hub):
    hub.add_channel("can1")
    with pytest.raises(can.CanError, match="could not open bus"):
        client(hub, "can9")


def test_on_input_runs_when_client_frames_arrive(hub):
    calls = []
    drive = can.Bus(interface="virtual", channel=hub.add_channel("can1", on_input=lambda: calls.append(drive.recv(0))))
    a = client(hub)
    try:
        a.send(frame(0x000, [0x01, 0x01]))
        deadline = time.monotonic() + 2.0
        while not calls and time.monotonic() < deadline:
            time.sleep(0.005)
        assert calls and calls[0].arbitration_id == 0 and bytes(calls[0].data) == b"\x01\x01"
    finally:
        a.shutdown()
        drive.shutdown()


def raw_socket(hub: CanHub, channel="can1") -> socket.socket:
    s = socket.create_connection((hub.host, hub.port), timeout=2.0)
    assert s.recv(256) == b"< hi >"
    s.sendall(f"< open {channel} >".encode())
    assert s.recv(256) == b"< ok >"
    s.sendall(b"< rawmode >")
    assert s.recv(256) == b"< ok >"
    return s


def test_frames_wait_for_a_client_that_just_entered_raw_mode(hub):
    """The stock client reads its ``< ok >`` with one recv(256) and compares it whole: frames must not follow
    it in the same read.  They wait until the client speaks, or RAW_GRACE passes."""
    drive = can.Bus(interface="virtual", channel=hub.add_channel("can1"))
    s = raw_socket(hub)
    try:
        drive.send(frame(0x701, [5]))
        hub.pump()
        s.settimeout(can_hub.RAW_GRACE / 4)
        with pytest.raises(socket.timeout):
            s.recv(256)
        s.settimeout(2.0)
        assert s.recv(256).startswith(b"< frame 701 ")          # after the grace
        s.sendall(b"< echo >")
        assert s.recv(256) == b"< echo >"
    finally:
        s.close()
        drive.shutdown()


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.binary(max_size=300))
def test_garbage_on_the_socket_is_counted_and_the_hub_serves_on(hub, junk):
    drive = can.Bus(interface="virtual", channel=hub.add_channel("can1"))
    s = raw_socket(hub)
    try:
        before = hub.stats.dropped_bytes + hub.stats.bad_commands
        s.sendall(junk + b"< send 7AB 1 42 >")
        got = drive.recv(2.0)
        while got is not None and got.arbitration_id != 0x7AB:
            got = drive.recv(0.5)
        assert got is not None and bytes(got.data) == b"\x42"
        if junk.strip(b" \t\r\n") and b">" not in junk:
            assert hub.stats.dropped_bytes + hub.stats.bad_commands > before
        assert hub.stats.errors == 0
    finally:
        s.close()
        drive.shutdown()
    good = client(hub)                       # still serving
    good.shutdown()


def test_a_closed_channel_disconnects_its_clients_and_the_shared_hub_is_refcounted():
    h = can_hub.acquire()
    try:
        assert can_hub.acquire() is h
        can_hub.release()
        h.add_channel("can7")
        s = raw_socket(h, "can7")
        h.remove_channel("can7")
        s.settimeout(2.0)
        assert s.recv(256) == b""
        s.close()
    finally:
        can_hub.release()
    assert can_hub._shared is None
    h2 = can_hub.acquire()
    try:
        assert h2 is not h
    finally:
        can_hub.release()
