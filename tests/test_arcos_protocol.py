"""ARCOS protocol module: bytes from the facts file (AriaCoda, verified there), the checksum p2os gets wrong,
argument forms of ARIA, p2os and Soar, SIP and CONFIGpac round trips, and the parser on any input."""
from __future__ import annotations

import math

import pytest
from hypothesis import example, given, settings, strategies as st

from runtime.drivers import arcos_protocol as P
from runtime.errors import InputError


def h(text: str) -> bytes:
    return bytes.fromhex(text)


# ----------------------------------------------------------------------------- bytes from the facts file
@pytest.mark.parametrize("n, wire", [(0, "fa fb 03 00 00 00"), (1, "fa fb 03 01 00 01"), (2, "fa fb 03 02 00 02")])
def test_sync_packets(n, wire):
    assert P.sync(n) == h(wire)


def test_enable_1():
    assert P.enable(True) == h("fa fb 06 04 3b 01 00 05 3b")


def test_vel_200_and_minus_200():
    assert P.vel(200) == h("fa fb 06 0b 3b c8 00 d3 3b")
    assert P.vel(-200) == h("fa fb 06 0b 1b c8 00 d3 1b")


def test_vel2_left_minus_5_right_10():
    """ARIA's com2Bytes: (short)((left & 0xff) << 8) + (right & 0xff) through comInt: NINTARG, magnitude 1270."""
    assert P.vel2_value(-5, 10) == -1270
    wire = P.vel2(-5, 10)
    assert wire[3:7] == h("20 1b f6 04")
    assert wire == P.frame(h("20 1b f6 04"))
    assert P.vel2_wheels(P.parse_command(wire[3:-2]).value) == (-5, 10)


@given(st.integers(-128, 127), st.integers(-128, 127))
@example(left=-128, right=0)                 # -32768: NINTARG with magnitude 0x8000
def test_vel2_round_trip(left, right):
    assert P.vel2_wheels(P.parse_command(P.vel2(left, right)[3:-2]).value) == (left, right)


def test_checksum_odd_length_xors_the_last_byte():
    body = h("0b 3b c8")                       # (0x0b3b) ^ 0xc8
    assert P.checksum(body) == 0x0B3B ^ 0xC8
    assert P.checksum(h("ff ff ff ff")) == 0xFFFE        # sums wrap at 16 bits


def test_a_packet_p2os_accepts_that_we_reject():
    good = P.vel(200)
    bad = bytearray(good)
    bad[-2] ^= 0x40                            # high checksum byte wrong; the low byte is non-zero
    bad = bytes(bad)
    assert P.p2os_accepts(good) and P.p2os_accepts(bad)
    parser = P.PacketParser()
    assert parser.feed(bad) == [] and parser.bad_checksum == 1
    assert parser.feed(good) == [good[3:-2]]
    corrupt_data = bytearray(good)
    corrupt_data[5] ^= 0x01                    # a flipped data bit: p2os takes this too
    assert P.p2os_accepts(bytes(corrupt_data))
    assert P.PacketParser().feed(bytes(corrupt_data)) == []


def test_named_commands():
    assert P.pulse() == P.frame(b"\x00")
    assert P.open_() == P.frame(h("01 3b 01 00"))                # ARIA: comInt(OPEN, 1)
    assert P.close() == P.frame(h("02 3b 01 00"))
    assert P.rvel(-30) == P.frame(h("15 1b 1e 00"))
    assert P.sonar(False) == P.frame(h("1c 3b 00 00"))
    assert P.seto() == P.frame(b"\x07") and P.stop() == P.frame(b"\x1d") and P.e_stop() == P.frame(b"\x37")
    assert P.config() == P.frame(h("12 3b 01 00"))


@pytest.mark.parametrize("call", [lambda: P.sync(3), lambda: P.int_arg(40000), lambda: P.vel2(200, 0),
                                  lambda: P.str_arg("x" * 200), lambda: P.frame(b""), lambda: P.robot_params("p2dx")])
def test_bad_arguments_are_one_line_input_errors(call):
    with pytest.raises(InputError) as exc:
        call()
    assert "\n" not in str(exc.value) and "expected" in str(exc.value)


# ----------------------------------------------------------------------------- argument forms
def test_string_forms_of_aria_and_soar():
    aria, soar = P.str_arg("hello"), P.str_arg(b"hello", length_byte=False)
    assert aria == b"\x2b\x05hello\x00" and soar == b"\x2bhello\x00"
    for arg in (aria, soar, b"\x2b\x05hello", b"\x2bhello"):
        assert P.parse_command(bytes([P.SAY]) + arg) == P.Command(P.SAY, "str", b"hello")


def test_polling_sequence_of_sonar_numbers_in_both_forms():
    seq = bytes([1, 2, 3, 16])
    for arg in (P.str_arg(seq), P.str_arg(seq, length_byte=False)):
        assert P.parse_command(bytes([P.POLLING]) + arg).value == seq


@pytest.mark.parametrize("body, expected", [
    (h("01"), P.Command(1, "none")),                       # p2os: OPEN bare
    (h("01 3b 01 00"), P.Command(1, "int", 1)),            # ARIA: comInt(OPEN, 1)
    (h("0b 1b c8 00"), P.Command(11, "int", -200)),
    (h("0b 3b c8"), P.Command(11, "raw", h("3b c8"))),     # cut short
    (h("0b 99 01 02"), P.Command(11, "raw", h("99 01 02"))),
])
def test_parse_command_forms(body, expected):
    assert P.parse_command(body) == expected


@given(st.binary(min_size=1, max_size=40))
def test_parse_command_never_raises(body):
    cmd = P.parse_command(body)
    assert cmd.id == body[0] and cmd.kind in ("none", "int", "str", "raw")


# ----------------------------------------------------------------------------- replies
def test_sync2_reply_names_and_lower_cases_the_subclass():
    body = P.sync2_reply("MobileSim", "Pioneer", "P3DX-SH")
    assert P.parse_sync2(body) == ("MobileSim", "Pioneer", "p3dx-sh")
    assert P.parse_sync2(b"\x02Robot\x00Pioneer") == ("Robot", "Pioneer", "")      # missing strings: empty


def test_config_packet_round_trip_in_aria_field_order():
    values = {"robot_class": "Pioneer", "subclass": "p3dx-sh", "serial": "SIM", "name": "x", "watchdog_ms": 2000,
              "sip_cycle_ms": 100, "drift_factor": -3, "firmware": "1.9", "charge_threshold": 7}
    out = P.decode_config(P.encode_config(values))
    assert {k: out[k] for k in values} == values
    assert len(out) == len(P.CONFIG_FIELDS)
    assert P.decode_config(P.encode_config(values)[:20])["robot_class"] == "Pioneer"     # short: leading fields


# ----------------------------------------------------------------------------- SIP
FULL_TAIL = dict(grip_anport=0x0102, analog=3, digin=4, digout=5, battery_x10=129, charge_state=1, rot_vel_x10=-455,
                 fault_flags=0x0010, lat_vel=-2, temperature=-5, state_of_charge=87, uc_time_us=0xDEADBEEF,
                 flags3=0x01020304)


def test_sip_round_trip_with_the_whole_tail():
    sip = P.Sip(x=0x7FF0, y=12, th=-1024, left_vel=-300, right_vel=310, battery_dv=128, stall_bumpers=0x0301,
                control=5, flags=0x0007, compass=90, sonars=((0, 5000), (3, 812), (15, 40)), moving=True, **FULL_TAIL)
    body = P.encode_sip(sip)
    assert body[0] == 0x33
    assert P.decode_sip(body) == sip


def test_sip_byte_layout_is_little_endian_as_aria_reads_it():
    body = P.encode_sip(P.Sip(x=0x1234, y=0x0056, th=-2, left_vel=-1, right_vel=256, battery_dv=120,
                              sonars=((2, 0x0304),)))
    assert body[:11] == h("32 34 12 56 00 fe ff ff ff 00 01")
    assert body[11] == 120
    assert body[18] == 0 and body[19] == 1 and body[20:23] == h("02 04 03")     # compass, count, reading
    assert len(body) == 23                                    # no tail


@pytest.mark.parametrize("cut", range(len(P.SIP_TAIL) + 1))
def test_the_tail_is_read_while_bytes_remain(cut):
    names = [n for n, _ in P.SIP_TAIL]
    tail = {n: FULL_TAIL[n] for n in names[:cut]}
    sip = P.Sip(x=1, sonars=((1, 100),), **tail)
    got = P.decode_sip(P.encode_sip(sip))
    assert got == sip
    assert all(getattr(got, n) is None for n in names[cut:])


def test_xpos_ypos_are_fifteen_bits_and_wrap_like_aria():
    body = bytearray(P.encode_sip(P.Sip()))
    body[1:3] = (0xFFFF).to_bytes(2, "little")
    assert P.decode_sip(bytes(body)).x == 0x7FFF
    assert P.wrap15(5 - 0x7FFB) == 10                  # 0x7FFB -> 5 across the wrap: +10 mm
    assert P.wrap15(0x7FFB - 5) == -10
    assert P.wrap15(0x0FFF) == 0x0FFF and P.wrap15(-0x0FFF) == -0x0FFF


@given(st.integers(0, 0x7FFF), st.integers(-0x0FFF, 0x0FFF))
def test_wrap15_recovers_any_step_within_a_sip_cycle(start, step):
    assert P.wrap15(((start + step) & 0x7FFF) - start) == step


@pytest.mark.parametrize("body", [b"", b"\x32", h("20 00"), P.encode_sip(P.Sip(sonars=((1, 1), (2, 2))))[:-1]])
def test_short_or_foreign_sips_raise_sip_error(body):
    with pytest.raises(P.SipError):
        P.decode_sip(body)


@settings(max_examples=300, deadline=None)
@given(st.binary(min_size=0, max_size=120))
def test_decode_sip_raises_only_sip_error(tail):
    try:
        P.decode_sip(b"\x32" + tail)
    except P.SipError:
        pass


# ----------------------------------------------------------------------------- parser
def _packets():
    bodies = st.binary(min_size=1, max_size=60)
    return st.lists(bodies, min_size=1, max_size=6)


FILL = bytes(P.MAX_COUNT + 3)            # enough bytes to settle any count a corrupted packet claims


def _accounts(p: P.PacketParser) -> bool:
    return p.packet_bytes + p.dropped_bytes + p.pending == p.fed


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(max_size=80), max_size=8))
def test_random_bytes_never_raise_and_every_byte_is_accounted_for(chunks):
    p = P.PacketParser()
    for c in chunks:
        p.feed(c)
    assert _accounts(p)


@settings(max_examples=200, deadline=None)
@given(_packets(), st.data())
def test_any_chunking_gives_the_same_packets(bodies, data):
    stream = b"".join(P.frame(b) for b in bodies)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=6)))
    p, out, last = P.PacketParser(), [], 0
    for c in cuts + [len(stream)]:
        out += p.feed(stream[last:c])
        last = c
    assert out == bodies and p.packets == len(bodies) and p.dropped_bytes == 0 and _accounts(p)


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=60), _packets())
def test_packets_after_garbage_are_found(garbage, bodies):
    p = P.PacketParser()
    out = p.feed(garbage + b"".join(P.frame(b) for b in bodies) + FILL)   # a false header's count settles
    assert out[-len(bodies):] == bodies and _accounts(p) and p.pending == 0


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=60), _packets(), st.integers(3, P.MAX_COUNT))
def test_packets_after_garbage_are_found_at_once_even_behind_a_stray_header(garbage, bodies, count):
    """No FILL this time: a stray header with a long count (the garbage's last bytes) does not hold back the
    complete good packets after it (``stale_headers``)."""
    p = P.PacketParser()
    out = p.feed(garbage + P.HEADER + bytes([count]) + b"".join(P.frame(b) for b in bodies))
    assert out[-len(bodies):] == bodies and _accounts(p) and p.pending == 0


@settings(max_examples=200, deadline=None)
@given(_packets(), st.integers(1, 40), st.binary(min_size=1, max_size=1))
@example([b"\x00I\x00\xb1"], 8, b"\x00")     # its checksum's last byte is the next packet's first sync byte
def test_a_truncated_packet_is_held_then_dropped_when_the_next_one_comes(bodies, cut, _):
    wire = P.frame(bodies[0])
    cut = min(cut, len(wire) - 1)
    follow = b"".join(P.frame(b) for b in bodies[1:]) + P.frame(b"\x00")
    p = P.PacketParser()
    assert p.feed(wire[:cut]) == []
    out = p.feed(follow + FILL)               # the cut packet's count may claim bytes of the ones after it
    assert _accounts(p) and p.pending == 0
    completed = wire[:cut] + (follow + FILL)[:len(wire) - cut]
    if P.PacketParser().feed(completed):      # the next bytes happen to complete it with a good checksum (1 in 256
        return                                # for one byte missing): a packet on the wire, and what followed is cut
    assert out[-1] == b"\x00"


@settings(max_examples=300, deadline=None)
@given(_packets(), st.data())
def test_bit_flips_are_rejected_or_counted_never_raised(bodies, data):
    stream = bytearray(b"".join(P.frame(b) for b in bodies))
    flips = data.draw(st.lists(st.tuples(st.integers(0, len(stream) - 1), st.integers(0, 7)), min_size=1, max_size=3))
    for pos, bit in flips:
        stream[pos] ^= 1 << bit
    p = P.PacketParser()
    out = p.feed(bytes(stream) + P.frame(b"\x42\x01") + FILL)
    assert _accounts(p) and p.pending == 0
    assert out and out[-1] == b"\x42\x01"          # the next good packet is found once a bad count is used up
    assert len(out) - 1 <= len(bodies)


def test_a_false_header_inside_a_packet_does_not_hide_the_next_one():
    p = P.PacketParser()
    decoy = h("fa fb 30")                       # promises 48 bytes that never come as such
    out = p.feed(decoy + P.vel(200) + P.vel(-200) + b"\x00" * 48)
    assert out == [P.vel(200)[3:-2], P.vel(-200)[3:-2]]
    assert p.bad_checksum == 1 and _accounts(p)


def test_impossible_counts_are_counted():
    p = P.PacketParser()
    assert p.feed(h("fa fb 02 00 00") + P.pulse()) == [b"\x00"]
    assert p.bad_count == 1 and _accounts(p)


# ----------------------------------------------------------------------------- parameters
def test_p3dx_sh_parameters():
    pr = P.P3DX_SH
    assert len(pr.sonar_units) == 16 and pr.sonar_units[3] == P.SonarUnit(166, 27, 10)
    assert pr.track_mm == pytest.approx(357.14, abs=0.01)
    assert pr.angle_conv * 4096 == pytest.approx(2 * math.pi) and pr.angle_conv == pytest.approx(0.00153, abs=1e-5)
    assert (pr.radius_mm, pr.max_vel_mm_s, pr.max_rvel_deg_s, pr.vel2_divisor) == (250, 2200, 500, 20)


@pytest.mark.parametrize("num, rng_mm", [(3, 1000), (0, 500), (11, 2000), (7, 0)])
def test_sonar_point_is_the_echo_seen_from_the_centre(num, rng_mm):
    u = P.P3DX_SH.sonar_units[num]
    bearing, dist = P.P3DX_SH.sonar_point(num, rng_mm)
    ex = u.x + rng_mm * math.cos(math.radians(u.heading))
    ey = u.y + rng_mm * math.sin(math.radians(u.heading))
    assert dist * 1000 * math.cos(bearing) == pytest.approx(ex) and dist * 1000 * math.sin(bearing) == pytest.approx(ey)
    if rng_mm == 0:
        assert dist == pytest.approx(math.hypot(u.x, u.y) / 1000)
