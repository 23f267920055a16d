"""The socketcand ASCII protocol (server side): the strings of the facts file, agreement with python-can's own
client-side converters, and random, truncated and bit-flipped input that never raises and is counted."""
from __future__ import annotations

import can
import pytest
from can.interfaces.socketcand.socketcand import (convert_ascii_message_to_can_message,
                                                  convert_can_message_to_ascii_message)
from hypothesis import given, strategies as st

from sitl import socketcand_protocol as S


def feed_all(chunks):
    sp = S.Splitter()
    out = []
    for c in chunks:
        out += sp.feed(c)
    return sp, out


def conserved(sp: S.Splitter) -> bool:
    s = sp.stats
    return s.bytes == s.command_bytes + s.dropped_bytes + s.between_bytes + sp.buffered


# ----------------------------------------------------------------------------- facts
def test_the_stock_client_handshake_and_send_strings():
    """Facts file: server ``< hi >``, client ``< open can0 >``, ``< ok >``, ``< rawmode >``, ``< ok >``; client
    ``< send ID DLC b0 b1 ... >``."""
    sp, cmds = feed_all([b"< open can0 >< rawmode >< send 601 8 2f 60 60 0 3 0 0 0 >"])
    assert cmds == ["open can0", "rawmode", "send 601 8 2f 60 60 0 3 0 0 0"]
    assert S.command(cmds[0]) == ("open", ["can0"])
    msg = S.parse_send(S.command(cmds[2])[1])
    assert (msg.arbitration_id, msg.is_extended_id, bytes(msg.data)) == (0x601, False, bytes.fromhex("2f60600003000000"))
    assert conserved(sp)


def test_frame_format_is_what_the_stock_client_parses():
    """``< frame ID SEC.USEC HEXDATA >``; a three-digit ID is standard, eight digits extended."""
    line = S.format_frame(can.Message(arbitration_id=0x701, data=[5], is_extended_id=False), 1712345678.000123)
    assert line == "< frame 701 1712345678.000123 05 >"
    back = convert_ascii_message_to_can_message(line)
    assert (back.arbitration_id, back.is_extended_id, bytes(back.data), back.timestamp) == \
        (0x701, False, b"\x05", 1712345678.000123)
    ext = S.format_frame(can.Message(arbitration_id=0x18FF50E5, data=b"", is_extended_id=True), 1.5)
    assert ext == "< frame 18FF50E5 1.500000  >"
    back = convert_ascii_message_to_can_message(ext)
    assert back.is_extended_id and back.arbitration_id == 0x18FF50E5 and bytes(back.data) == b""


frames = st.builds(
    lambda ext, ident, data: can.Message(arbitration_id=ident & (0x1FFFFFFF if ext else 0x7FF), is_extended_id=ext,
                                         data=data),
    st.booleans(), st.integers(0, 0x1FFFFFFF), st.binary(max_size=8))


@given(frames)
def test_parse_send_reads_what_the_stock_client_writes(msg):
    text = convert_can_message_to_ascii_message(msg)
    sp, cmds = feed_all([text.encode()])
    assert len(cmds) == 1
    verb, args = S.command(cmds[0])
    back = S.parse_send(args)
    assert verb == "send" and back is not None
    assert (back.arbitration_id, back.is_extended_id, bytes(back.data)) == \
        (msg.arbitration_id, msg.is_extended_id, bytes(msg.data))


@given(frames, st.floats(0, 4e9))
def test_format_frame_round_trips_through_the_stock_parser(msg, t):
    back = convert_ascii_message_to_can_message(S.format_frame(msg, t))
    assert (back.arbitration_id, back.is_extended_id, bytes(back.data)) == \
        (msg.arbitration_id, msg.is_extended_id, bytes(msg.data))


@pytest.mark.parametrize("args", [
    [], ["601"], ["601", "9"] + ["0"] * 9, ["601", "2", "1"], ["601", "2", "1", "2", "3"], ["800", "0"],
    ["1234", "0"], ["20000000", "0"], ["601", "1", "100"], ["60g", "0"], ["601", "x"], ["601", "1", "-1"],
])
def test_parse_send_refuses_what_is_not_a_frame(args):
    assert S.parse_send(args) is None


# ----------------------------------------------------------------------------- framing
def test_splitter_resyncs_and_counts():
    sp, cmds = feed_all([b"junk< echo >\r\n< open ", b"can1 >< send 601 1 1", b"< rawmode >\xff< a\xffb >"])
    assert cmds == ["echo", "open can1", "rawmode"]
    s = sp.stats
    assert s.truncated == 1 and s.non_ascii == 1 and s.dropped_bytes >= 4 and s.between_bytes == 2
    assert conserved(sp)


def test_an_overlong_command_is_dropped_up_to_its_end():
    sp, cmds = feed_all([b"< " + b"x" * (S.MAX_COMMAND + 10) + b" >< echo >"])
    assert cmds == ["echo"] and sp.stats.too_long == 1 and conserved(sp)


@given(st.binary(max_size=600), st.integers(1, 64))
def test_random_bytes_never_raise_and_every_byte_is_accounted_for(data, size):
    sp, cmds = feed_all([data[i:i + size] for i in range(0, len(data), size)])
    assert conserved(sp)
    for c in cmds:
        verb, args = S.command(c)
        if verb == "send":
            S.parse_send(args)


good = b"< open can1 >< rawmode >< send 601 8 2f 60 60 0 3 0 0 0 >< send 000 2 1 1 >< send 77F 1 5 >"


@given(st.integers(0, len(good)), st.integers(1, 16))
def test_truncated_input_never_raises(cut, size):
    data = good[:cut]
    sp, cmds = feed_all([data[i:i + size] for i in range(0, len(data), size)])
    assert conserved(sp)
    assert len(cmds) == data.count(b">")


@given(st.lists(st.tuples(st.integers(0, len(good) - 1), st.integers(0, 7)), min_size=1, max_size=8))
def test_bit_flipped_input_never_raises_and_bad_sends_are_refused(flips):
    data = bytearray(good)
    for pos, bit in flips:
        data[pos] ^= 1 << bit
    sp, cmds = feed_all([bytes(data)])
    assert conserved(sp)
    parsed = [S.parse_send(S.command(c)[1]) for c in cmds if S.command(c)[0] == "send"]
    assert len(cmds) + sp.stats.truncated + sp.stats.non_ascii + sp.stats.too_long <= 5 + len(flips)
    for msg in parsed:
        assert msg is None or 0 <= msg.dlc <= 8
