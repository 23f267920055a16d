"""Create OI protocol: spec examples byte for byte, the packet table, round trips, and both parsers
under random, truncated and garbled input."""
from __future__ import annotations

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from runtime.drivers import create_oi_protocol as P
from runtime.errors import InputError

MODELS = P.MODELS


# ----------------------------------------------------------------------------- spec examples
def test_drive_spec_example_reverse_200_radius_500():
    # Create 2 OI spec, Drive: "-200 mm/s while turning at a radius of 500 mm: [137] [255] [56] [1] [244]"
    assert P.drive(-200, 500) == bytes([137, 255, 56, 1, 244])


def test_drive_special_radii():
    assert P.drive(300, 32768) == bytes([137, 1, 44, 0x80, 0x00])       # straight
    assert P.drive(300, 32767) == bytes([137, 1, 44, 0x7F, 0xFF])       # straight (alternative)
    assert P.drive(300, -1) == bytes([137, 1, 44, 0xFF, 0xFF])          # clockwise in place
    assert P.drive(300, 0xFFFF) == bytes([137, 1, 44, 0xFF, 0xFF])
    assert P.drive(300, 1) == bytes([137, 1, 44, 0x00, 0x01])           # counter-clockwise in place


def test_create1_script_examples_parse_into_their_commands():
    # Create OI v2 spec, Script: "Drive in a square: 152 17 137 1 44 128 0 156 1 144 137 1 44 0 1 157 0 90 153"
    square = bytes([152, 17, 137, 1, 44, 128, 0, 156, 1, 144, 137, 1, 44, 0, 1, 157, 0, 90, 153])
    p = P.CommandParser("create1")
    [(op, script)] = p.feed(square)
    assert op == P.SCRIPT and script[0] == 17 and len(script) == 18
    inner = P.CommandParser("create1").feed(script[1:])
    assert inner == [(137, bytes([1, 44, 128, 0])), (156, bytes([1, 144])), (137, bytes([1, 44, 0, 1])),
                     (157, bytes([0, 90])), (153, b"")]
    # the same drive commands from the encoder: 300 mm/s straight, 300 mm/s counter-clockwise in place
    assert bytes([137]) + inner[0][1] == P.drive(300, P.RADIUS_STRAIGHT)
    assert bytes([137]) + inner[2][1] == P.drive(300, P.RADIUS_CCW)
    # "Drive 40 cm and stop: 152 13 137 1 44 128 0 156 1 144 137 0 0 0 0"
    [(op, script)] = P.CommandParser("create1").feed(bytes([152, 13, 137, 1, 44, 128, 0, 156, 1, 144, 137, 0, 0, 0, 0]))
    inner = P.CommandParser("create1").feed(script[1:])
    assert inner[1] == (P.WAIT_DISTANCE, (400).to_bytes(2, "big")) and inner[2] == (137, bytes(4))


def test_create1_guide_examples():
    # Create owner's guide: "128 132 139 2 0 0" (Play LED on) and "128 142 9" (read the left cliff sensor)
    p = P.CommandParser("create1")
    assert p.feed(bytes([128, 132, 139, 2, 0, 0, 128, 142, 9])) == [
        (128, b""), (132, b""), (139, bytes([2, 0, 0])), (128, b""), (142, bytes([9]))]
    assert P.leds(2, 0, 0) == bytes([139, 2, 0, 0]) and P.sensors(9) == bytes([142, 9])
    # PWM Low Side Drivers: "driver 2 at 25% and driver 0 at 100%: [144][32][0][128]"
    assert p.feed(bytes([144, 32, 0, 128])) == [(144, bytes([32, 0, 128]))]


def test_song_example_encodes_and_parses():
    # Create 2 OI spec, Song: [140] [0] [4] [62] [12] [66] [12] [69] [12] [74] [36]
    example = bytes([140, 0, 4, 62, 12, 66, 12, 69, 12, 74, 36])
    assert P.song(0, [(62, 12), (66, 12), (69, 12), (74, 36)]) == example
    assert P.CommandParser().feed(example) == [(140, example[1:])]


def test_stream_spec_example_frame():
    # Create 2 OI spec, Stream: [148] [2] [29] [13] answered by 19 5 29 2 25 13 0 163
    assert P.stream([29, 13]) == bytes([148, 2, 29, 13])
    frame = bytes([19, 5, 29, 2, 25, 13, 0, 163])
    assert sum(frame) & 0xFF == 0
    parser = P.StreamParser()
    assert parser.feed(frame) == [{"cliff_front_left_signal": 0x0219, "virtual_wall": 0}]
    assert 0x0219 == 537
    assert (parser.frames, parser.bad_checksum, parser.dropped_bytes, parser.pending) == (1, 0, 0, 0)
    chunks = [(29, P.encode_packet(29, {"cliff_front_left_signal": 537})),
              (13, P.encode_packet(13, {"virtual_wall": 0}))]
    assert P.build_stream_frame(chunks) == frame
    assert P.checksum(frame[:-1]) == 163


def test_other_input_commands():
    assert P.query_list([9, 13]) == bytes([149, 2, 9, 13])
    assert P.pause_resume_stream(False) == bytes([150, 0])
    assert P.pause_resume_stream(True) == bytes([150, 1])
    assert P.drive_direct(100, -100) == bytes([145, 0, 100, 255, 156])   # right first, then left
    assert P.drive_pwm(255, -255) == bytes([146, 0, 255, 255, 1])
    assert P.start() + P.safe() + P.full() + P.stop() + P.reset() == bytes([128, 131, 132, 173, 7])
    assert P.baud(11) == bytes([129, 11]) and P.BAUD_RATES[P.baud_code(57600)] == 57600


@pytest.mark.parametrize("call", [
    lambda: P.drive(501, 0), lambda: P.drive(0, 2001), lambda: P.drive(0, -2001), lambda: P.drive(1.5, 0),
    lambda: P.drive_direct(0, -501), lambda: P.drive_pwm(256, 0), lambda: P.sensors(59),
    lambda: P.sensors(43, model="create1"), lambda: P.stream([100, 7, 200]), lambda: P.baud(12),
    lambda: P.baud_code(12345), lambda: P.song(5, [(60, 8)]), lambda: P.song(0, []),
    lambda: P.decode_packet(7, b"\x00\x00"), lambda: P.decode_packet(99, b""),
    lambda: P.encode_packet(19, {}), lambda: P.packet_members(101, "create1"), lambda: P.StreamParser("roomba"),
])
def test_bad_arguments_raise_one_line_input_errors(call):
    with pytest.raises(InputError) as exc:
        call()
    msg = str(exc.value)
    assert "\n" not in msg and "expected" in msg


# ----------------------------------------------------------------------------- packet table
GROUP_SIZES = {0: 26, 1: 10, 2: 6, 3: 10, 4: 14, 5: 12, 6: 52, 100: 80, 101: 28, 106: 12, 107: 9}


@pytest.mark.parametrize("model", MODELS)
def test_group_sizes_match_the_spec_quick_reference(model):
    groups = P.group_ids(model)
    assert groups == ((0, 1, 2, 3, 4, 5, 6, 100, 101, 106, 107) if model == "create2" else (0, 1, 2, 3, 4, 5, 6))
    for g in groups:
        assert P.packet_size(g, model) == GROUP_SIZES[g]
        assert P.packet_size(g, model) == sum(P.packet_size(m, model) for m in P.packet_members(g, model))


def test_packet_table_facts():
    c2, c1 = P.packet_specs("create2"), P.packet_specs("create1")
    assert sorted(c2) == list(range(7, 59)) and sorted(c1) == list(range(7, 43))
    signed = {19, 20, 23, 24, 39, 40, 41, 42, 43, 44, 54, 55, 56, 57}
    assert {pid for pid, s in c2.items() if s.signed} == signed
    two_bytes = {19, 20, 22, 23, 25, 26, 27, 28, 29, 30, 31, 33, 39, 40, 41, 42, 43, 44, 46, 47, 48, 49, 50, 51,
                 54, 55, 56, 57}
    assert {pid for pid, s in c2.items() if s.size == 2} == two_bytes
    assert c2[7].bits == ((0, "bump_right"), (1, "bump_left"), (2, "wheel_drop_right"), (3, "wheel_drop_left"))
    assert (4, "wheel_drop_caster") in c1[7].bits
    assert (c2[27].hi, c1[27].hi) == (1023, 4095)           # wall signal range differs
    assert c1[32].name == "cargo_bay_digital_inputs" and c2[32].name == "unused_32"
    assert (c2[22].unit, c2[23].unit, c2[25].unit, c2[19].unit, c2[20].unit) == ("mV", "mA", "mAh", "mm", "deg")
    assert P.packet_ids("create2") == tuple(range(0, 7)) + tuple(range(7, 59)) + (100, 101, 106, 107)
    g = P.GEOMETRY["create2"]
    assert g.mm_per_count == pytest.approx(0.444565, rel=1e-5)
    assert (g.track_mm, P.GEOMETRY["create1"].track_mm) == (235.0, 258.0)
    assert (g.default_baud, P.GEOMETRY["create1"].default_baud) == (115200, 57600)


def test_group_100_decodes_every_packet_in_order():
    data = bytes(range(80))
    values = P.decode_packet(100, data)
    assert values["bumps_wheel_drops"] == 0 and values["wall"] == 1
    assert values["distance"] == (12 << 8 | 13) and values["voltage"] == (17 << 8 | 18)
    assert values["temperature"] == 21 and values["stasis"] == 79
    assert values["left_encoder_counts"] == (52 << 8 | 53) and values["right_encoder_counts"] == (54 << 8 | 55)
    assert P.decode_packet(43, b"\xff\xfe") == {"left_encoder_counts": -2}     # signed per spec


def _single_strategy(model):
    specs = P.packet_specs(model)
    return st.sampled_from(sorted(specs)).flatmap(
        lambda pid: st.tuples(st.just(pid), st.integers(specs[pid].lo, specs[pid].hi)))


@pytest.mark.parametrize("model", MODELS)
def test_every_packet_id_round_trips_its_bytes(model):
    for pid in P.packet_ids(model):
        size = P.packet_size(pid, model)
        for data in (bytes(size), bytes([0xFF]) * size, bytes((i * 37 + 11) & 0xFF for i in range(size))):
            values = P.decode_packet(pid, data, model)
            assert P.encode_packet(pid, values, model) == data
            flags_only = {k: v for k, v in values.items() if isinstance(v, bool)}
            for spec in (P.packet_specs(model)[m] for m in P.packet_members(pid, model)):
                if spec.bits:
                    mask = sum(1 << b for b, _ in spec.bits)
                    rebuilt = P.encode_packet(spec.id, flags_only, model)[0]
                    assert rebuilt == values[spec.name] & mask


@pytest.mark.parametrize("model", MODELS)
@settings(max_examples=150, deadline=None)
@given(data=st.data())
def test_round_trip_random_bytes_and_values(model, data):
    pid = data.draw(st.sampled_from(P.packet_ids(model)))
    raw = data.draw(st.binary(min_size=P.packet_size(pid, model), max_size=P.packet_size(pid, model)))
    values = P.decode_packet(pid, raw, model)
    assert P.encode_packet(pid, values, model) == raw
    assert P.decode_packet(pid, P.encode_packet(pid, values, model), model) == values
    single, value = data.draw(_single_strategy(model))
    name = P.packet_specs(model)[single].name
    assert P.decode_packet(single, P.encode_packet(single, {name: value}, model), model)[name] == value


def test_drive_to_wheels_follows_the_spec_definitions():
    b = 235.0
    assert P.drive_to_wheels(200, 0x8000, b) == (200, 200)
    assert P.drive_to_wheels(200, 0x7FFF, b) == (200, 200)
    assert P.drive_to_wheels(200, 0xFFFF, b) == (200, -200)        # clockwise: left forward
    assert P.drive_to_wheels(200, 1, b) == (-200, 200)             # counter-clockwise
    left, right = P.drive_to_wheels(-200, 500, b)                  # the spec example, reversing on a left arc
    assert (left + right) / 2 == pytest.approx(-200)
    assert (right - left) / b == pytest.approx(-200 / 500)         # turn rate v / R
    left, right = P.drive_to_wheels(200, (-500) & 0xFFFF, b)       # negative radius turns right
    assert right < left
    left, right = P.drive_to_wheels(500, 100, b)                   # a wheel over 500 mm/s scales both
    assert max(abs(left), abs(right)) == pytest.approx(500)
    assert (right - left) / (right + left) * 2 == pytest.approx(b / 100)   # same radius


# ----------------------------------------------------------------------------- stream parser
def _frame_strategy(model="create2", no19=False):
    """A valid frame of 1-4 random packets; with no19, no byte after the header is 19."""
    ids = [pid for pid in P.packet_ids(model) if P.packet_size(pid, model) <= 30]

    chunk = st.sampled_from(ids).flatmap(lambda pid: st.tuples(
        st.just(pid), st.binary(min_size=P.packet_size(pid, model), max_size=P.packet_size(pid, model))))
    frames = st.lists(chunk, min_size=1, max_size=4).map(P.build_stream_frame)
    if no19:
        frames = frames.filter(lambda f: P.STREAM_HEADER not in f[1:])
    return frames


def _accounted(p: P.StreamParser) -> bool:
    return p.frame_bytes + p.dropped_bytes + p.pending == p.fed


@settings(max_examples=200, deadline=None)
@given(st.lists(st.binary(max_size=300), max_size=6))
def test_stream_parser_random_bytes_never_raise_and_account_for_every_byte(chunks):
    for model in MODELS:
        p = P.StreamParser(model)
        for c in chunks:
            for frame in p.feed(c):
                assert isinstance(frame, dict)
            assert _accounted(p)
        assert p.pending <= 258


@settings(max_examples=150, deadline=None)
@given(frames=st.lists(_frame_strategy(), min_size=1, max_size=5), cuts=st.lists(st.integers(0, 2000), max_size=6))
def test_stream_parser_is_incremental(frames, cuts):
    stream = b"".join(frames)
    whole = P.StreamParser().feed(stream)
    assert len(whole) == len(frames)
    p, got, last = P.StreamParser(), [], 0
    for c in sorted(set(min(c, len(stream)) for c in cuts)) + [len(stream)]:
        got += p.feed(stream[last:c])
        last = c
    assert got == whole and p.dropped_bytes == 0 and p.pending == 0


@settings(max_examples=150, deadline=None)
@given(frame=_frame_strategy(), cut=st.integers(0, 300), more=st.lists(st.binary(max_size=40), max_size=3))
def test_stream_parser_truncated_frames_never_raise_and_are_counted(frame, cut, more):
    p = P.StreamParser()
    truncated = frame[:min(cut, len(frame) - 1)]
    assert p.feed(truncated) == []                    # a partial frame is held or dropped, never decoded
    assert _accounted(p)
    for c in more:
        p.feed(c)
        assert _accounted(p)


@settings(max_examples=150, deadline=None)
@given(garbage=st.binary(max_size=200).map(lambda g: g.replace(b"\x13", b"")),
       frames=st.lists(_frame_strategy(no19=True), min_size=1, max_size=4))
def test_valid_frames_after_garbage_are_decoded(garbage, frames):
    p = P.StreamParser()
    out = p.feed(garbage + b"".join(frames))
    assert out == [P.StreamParser().feed(f)[0] for f in frames]
    assert p.dropped_bytes == len(garbage) and _accounted(p)


@settings(max_examples=150, deadline=None)
@given(bad=_frame_strategy(no19=True), pos=st.integers(2, 400), value=st.integers(0, 255),
       good=st.lists(_frame_strategy(no19=True), min_size=1, max_size=3))
def test_a_garbled_frame_is_rejected_and_the_next_ones_decoded(bad, pos, value, good):
    pos = 2 + pos % (len(bad) - 2)                    # a data or checksum byte
    assume(value != bad[pos] and value != P.STREAM_HEADER)
    garbled = bad[:pos] + bytes([value]) + bad[pos + 1:]
    p = P.StreamParser()
    out = p.feed(garbled + b"".join(good))
    first_id_unknown = pos == 2 and value not in P.packet_ids()
    assert p.bad_checksum == (0 if first_id_unknown else 1)   # one changed byte always breaks the sum
    assert len(out) == len(good) and p.frames == len(good)
    assert p.dropped_bytes == len(garbled) and _accounted(p)


def test_resync_on_a_false_header_inside_garbage():
    frame = bytes([19, 5, 29, 2, 25, 13, 0, 163])
    p = P.StreamParser()
    out = p.feed(bytes([19, 3, 7, 1, 2, 19, 0]) + frame + frame)    # two false headers, bad checksums
    assert out == [{"cliff_front_left_signal": 537, "virtual_wall": 0}] * 2
    assert p.bad_checksum == 2 and p.dropped_bytes == 7 and _accounted(p)


def test_checksum_valid_frame_with_unknown_packets_is_malformed():
    body = bytes([19, 2, 8, 1])                    # packet 8 (wall) is one byte: n=2 fits
    ok = body + bytes([P.checksum(body)])
    assert P.StreamParser().feed(ok) == [{"wall": 1}]
    bad_body = bytes([19, 3, 8, 1, 1])             # packet 8 then a stray byte: n does not match the packets
    p = P.StreamParser()
    assert p.feed(bad_body + bytes([P.checksum(bad_body)])) == []
    assert p.malformed == 1 and _accounted(p)


# ----------------------------------------------------------------------------- command parser
def _command_strategy(model):
    table = P.COMMAND_LENGTHS[model]

    def args(op):
        spec = table[op]
        if spec == "song":
            return st.tuples(st.integers(0, 15), st.integers(0, 16)).flatmap(
                lambda t: st.binary(min_size=2 * t[1], max_size=2 * t[1]).map(lambda b: bytes(t) + b))
        if spec in ("list", "script"):
            return st.integers(0, 20).flatmap(lambda n: st.binary(min_size=n, max_size=n).map(lambda b: bytes([n]) + b))
        return st.binary(min_size=spec, max_size=spec)

    return st.sampled_from(sorted(table)).flatmap(lambda op: st.tuples(st.just(op), args(op)))


def _cmd_accounted(p: P.CommandParser) -> bool:
    return p.command_bytes + p.dropped_bytes + p.pending == p.fed


@settings(max_examples=200, deadline=None)
@given(st.lists(st.binary(max_size=200), max_size=6))
def test_command_parser_random_bytes_never_raise_and_account_for_every_byte(chunks):
    for model in MODELS:
        p = P.CommandParser(model)
        for c in chunks:
            for op, args in p.feed(c):
                assert op in P.COMMAND_LENGTHS[model] and isinstance(args, bytes)
            assert _cmd_accounted(p)
        assert p.unknown_opcodes == p.dropped_bytes


@pytest.mark.parametrize("model", MODELS)
@settings(max_examples=100, deadline=None)
@given(data=st.data())
def test_command_parser_recovers_every_command_in_any_chunking(model, data):
    cmds = data.draw(st.lists(_command_strategy(model), max_size=8))
    unknown = sorted(set(range(256)) - set(P.COMMAND_LENGTHS[model]))
    noise = data.draw(st.lists(st.binary(max_size=3).map(lambda b: bytes(unknown[x % len(unknown)] for x in b)),
                               min_size=len(cmds) + 1, max_size=len(cmds) + 1))
    stream = noise[0] + b"".join(bytes([op]) + a + n for (op, a), n in zip(cmds, noise[1:]))
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=5)))
    p, got, last = P.CommandParser(model), [], 0
    for c in cuts + [len(stream)]:
        got += p.feed(stream[last:c])
        last = c
    assert got == [(op, a) for op, a in cmds]
    assert p.unknown_opcodes == sum(map(len, noise)) and p.pending == 0 and _cmd_accounted(p)


@pytest.mark.parametrize("model", MODELS)
@settings(max_examples=100, deadline=None)
@given(data=st.data())
def test_command_parser_holds_a_truncated_command(model, data):
    op, args = data.draw(_command_strategy(model))
    cmd = bytes([op]) + args
    cut = data.draw(st.integers(0, len(cmd) - 1))
    p = P.CommandParser(model)
    assert p.feed(cmd[:cut]) == []
    assert p.pending == cut and _cmd_accounted(p)
    assert p.feed(cmd[cut:]) == [(op, args)]


def test_unknown_opcodes_are_counted_and_skipped():
    p = P.CommandParser("create2")
    assert p.feed(bytes([0, 200, 146, 0, 10, 0, 10, 152])) == [(146, bytes([0, 10, 0, 10]))]
    assert (p.unknown_opcodes, p.dropped_bytes) == (3, 3)           # 0, 200 and 152 (no scripts on a Create 2)
    p1 = P.CommandParser("create1")
    assert p1.feed(bytes([146, 173, 7])) == [] and p1.unknown_opcodes == 3   # no Drive PWM, Stop, Reset
