"""Mission files: QGC WPL 110 and .plan readers, the WPL writer, agreement with pymavlink's MAVWPLoader,
one-line errors, and random / truncated / bit-flipped input that yields items or InputError only."""
from __future__ import annotations

import math
import os
import tempfile
from dataclasses import replace
from pathlib import Path

import pymap3d
import pytest
from hypothesis import given, settings, strategies as st
from pymavlink import mavwp

from runtime.comms.mission import MissionItem
from runtime.comms.mission import MAX_ITEMS
from runtime.comms.mission_files import (MAX_FILE_BYTES, MissionFile, format_wpl, parse_plan, parse_wpl,
                                         read_mission, read_plan, read_wpl, write_wpl)
from runtime.errors import InputError

MISSIONS = Path(__file__).resolve().parents[1] / "configs" / "missions"
WPL = MISSIONS / "square_6.waypoints"
PLAN = MISSIONS / "square_6.plan"
DATUM = (33.7756, -84.3963, 300.0)
FIELDS = ("frame", "command", "param1", "param2", "param3", "param4", "x", "y", "z", "autocontinue")


def fields(obj) -> tuple:
    return tuple(float(getattr(obj, f)) for f in FIELDS)


# ------------------------------------------------------------------------------------------ examples

def test_examples_hold_the_same_six_waypoints_inside_the_arena():
    wpl, plan = read_wpl(WPL), read_plan(PLAN)
    assert wpl == plan and len(wpl.items) == 6 and wpl.home == DATUM
    assert [it.seq for it in wpl.items] == list(range(6))
    for it in wpl.items:
        assert (it.command, it.frame, it.mission_type) == (16, 3, 0)
        e, n, _ = pymap3d.geodetic2enu(it.x, it.y, DATUM[2], *DATUM)
        assert max(abs(e), abs(n)) < 5.0                  # arena_10m is +-5 m around the datum
    assert read_mission(WPL) == wpl and read_mission(PLAN) == plan


# ------------------------------------------------------------------------------------------ MAVWPLoader

def test_mavwploader_reads_our_example_as_we_do():
    loader = mavwp.MAVWPLoader()
    assert loader.load(str(WPL)) == 7                    # home + 6
    ours = read_wpl(WPL)
    home = loader.wp(0)
    assert (home.seq, home.current, (home.x, home.y, home.z)) == (0, 1, ours.home)
    for it in ours.items:
        assert fields(loader.wp(it.seq + 1)) == fields(it)


def test_mavwploader_saved_file_reads_back(tmp_path):
    loader = mavwp.MAVWPLoader()
    loader.load(str(WPL))
    loader.save(str(tmp_path / "saved.txt"))             # MAVProxy's writer: %f, 6 decimals
    again = read_wpl(tmp_path / "saved.txt")
    assert again.home == pytest.approx(DATUM)
    for a, b in zip(again.items, read_wpl(WPL).items, strict=True):
        assert fields(a) == pytest.approx(fields(b), abs=1e-6)


MIXED = [MissionItem(0, 3, 16, 1.0, 0.5, 0.0, math.nan, 33.7755731, -84.3963324, 2.0),
         MissionItem(1, 4, 17, x=1.25, y=-2.5, autocontinue=False),            # local ENU, loiter
         MissionItem(2, 2, 177, 0.0, 3.0),                                      # DO_JUMP to item 0, 3 times
         MissionItem(3, 5, 16, x=-33.5, y=151.25, z=math.nan)]


def test_write_then_read_is_exact_and_mavwploader_agrees(tmp_path):
    path = tmp_path / "m.waypoints"
    write_wpl(MIXED, path, home=DATUM)
    assert read_wpl(path) == MissionFile(MIXED, DATUM)
    loader = mavwp.MAVWPLoader()
    assert loader.load(str(path)) == len(MIXED) + 1
    assert loader.wp(3).command == 177 and loader.wp(3).param1 == 1.0      # line numbers count home
    for it in MIXED:
        if it.command == 177:
            it = replace(it, param1=it.param1 + 1)
        got, want = fields(loader.wp(it.seq + 1)), fields(it)
        assert all(g == w or (math.isnan(g) and math.isnan(w)) for g, w in zip(got, want)), it.seq


def test_write_without_home_uses_the_first_global_item():
    mf = parse_wpl(format_wpl(MIXED))
    assert mf.items == MIXED and mf.home == (MIXED[0].x, MIXED[0].y, 0.0)
    assert parse_wpl(format_wpl([])) == MissionFile([], None)


def test_first_line_is_home_only_when_marked_current():
    lines = ["QGC WPL 110",
             "0\t0\t3\t16\t0\t0\t0\t0\t33.1\t-84.1\t0\t1",
             "1\t0\t3\t16\t0\t0\t0\t0\t33.2\t-84.2\t0\t1"]
    mf = parse_wpl("\n".join(lines))
    assert mf.home is None and [it.x for it in mf.items] == [33.1, 33.2]
    lines[1] = lines[1].replace("0\t0\t3", "0\t1\t3", 1)
    mf = parse_wpl("\n".join(lines))
    assert mf.home == (33.1, -84.1, 0.0) and [(it.seq, it.x) for it in mf.items] == [(0, 33.2)]


def test_whitespace_comments_and_blank_lines():
    text = ("QGC WPL 110\r\n# from MAVProxy\r\n\r\n0 1 0 16 0 0 0 0 1 2 3 1\r\n"
            "  1  0  3  16 0 0 0 0  4 5 6 1  \r\n")
    assert parse_wpl(text).items == [MissionItem(0, 3, 16, x=4.0, y=5.0, z=6.0)]


def test_plan_nulls_do_jump_ids_and_ignored_sections():
    plan = """{"fileType": "Plan", "geoFence": {"polygons": [[1, 2]]}, "rallyPoints": {"points": [[1, 2, 3]]},
      "mission": {"items": [
        {"type": "SimpleItem", "command": 16, "frame": 3, "doJumpId": 5, "autoContinue": true,
         "params": [0, 0, 0, null, 33.5, -84.5, 10]},
        {"type": "SimpleItem", "command": 177, "frame": 2, "doJumpId": 6, "autoContinue": true,
         "params": [5, 2, 0, 0, 0, 0, 0]}]}}"""
    mf = parse_plan(plan, "p.plan")
    assert mf.home is None
    assert mf.items[0] == MissionItem(0, 3, 16, 0, 0, 0, math.nan, 33.5, -84.5, 10)
    assert (mf.items[1].command, mf.items[1].param1, mf.items[1].param2) == (177, 0.0, 2.0)


# ------------------------------------------------------------------------------------------ errors

GOOD_LINE = "1\t0\t3\t16\t0\t0\t0\t0\t33.5\t-84.5\t0\t1"


@pytest.mark.parametrize("text, message", [
    ("", "line 1: expected 'QGC WPL 110', got ''"),
    ("QGC WPL 100\n", "line 1: expected 'QGC WPL 110', got 'QGC WPL 100'"),
    (f"QGC WPL 110\n{GOOD_LINE}\n\n1 0 3 16 0 0 0 0 1\n", "line 4: expected 12 fields, got 9"),
    ("QGC WPL 110\n1 0 3 sixteen 0 0 0 0 1 2 3 1", "line 2: COMMAND: expected an integer, got 'sixteen'"),
    ("QGC WPL 110\n1 0 3 16 0 0 0 0 1 2 3 2", "line 2: AUTOCONTINUE: expected 0..1, got 2"),
    ("QGC WPL 110\n1 0 3 16 0 0 0 x 1 2 3 1", "line 2: PARAM4: expected a number, got 'x'"),
    ("QGC WPL 110\n1 0 3 16 0 0 0 0 91 2 3 1", "line 2: X: expected a latitude in -90..90, got 91.0"),
    ("QGC WPL 110\n1 0 3 16 0 0 0 0 1 inf 3 1", "line 2: Y: expected a longitude in -180..180, got inf"),
    ("QGC WPL 110\n1 0 1 16 0 0 0 0 1e6 0 0 1", "line 2: x 1000000.0 does not fit an int32 in frame 1"),
    # the INDEX column counts up by one: a line lost from the middle, or repeated, is refused
    (f"QGC WPL 110\n0 1 0 16 0 0 0 0 1 2 3 1\n{GOOD_LINE}\n3 0 3 16 0 0 0 0 1 2 3 1\n",
     "line 4: INDEX: expected 2 (a line lost or repeated?), got 3"),
    (f"QGC WPL 110\n{GOOD_LINE}\n# note\n{GOOD_LINE}\n", "line 4: INDEX: expected 2 (a line lost or repeated?), got 1"),
    ("QGC WPL 110\n5 0 3 16 0 0 0 0 1 2 3 1", "line 2: INDEX: expected 0 (or 1 in a file without a home line), got 5"),
])
def test_wpl_errors_are_one_line_naming_file_and_line(text, message):
    with pytest.raises(InputError) as e:
        parse_wpl(text, "mission.txt")
    assert str(e.value) == f"mission.txt: {message}"


def _wpl_of(n: int, home: bool) -> str:
    first = ["0\t1\t0\t16\t0\t0\t0\t0\t1\t2\t0\t1"] if home else []
    return "\n".join(["QGC WPL 110", *first] + [f"{i + home}\t0\t3\t16\t0\t0\t0\t0\t33.5\t-84.5\t0\t1"
                                                  for i in range(n)]) + "\n"


@pytest.mark.parametrize("home", [False, True])
def test_a_wpl_file_of_more_items_than_a_robot_takes_is_refused(home):
    assert len(parse_wpl(_wpl_of(MAX_ITEMS, home)).items) == MAX_ITEMS
    with pytest.raises(InputError) as e:
        parse_wpl(_wpl_of(MAX_ITEMS + 1, home), "big.txt")
    assert str(e.value) == (f"big.txt: line {MAX_ITEMS + 2 + home}: expected at most {MAX_ITEMS} items (what a robot "
                            "takes), got more")
    with pytest.raises(InputError, match=rf"^p: mission.items: expected at most {MAX_ITEMS} items .*, got 1001$"):
        parse_plan(_plan("[" + ", ".join([SIMPLE] * (MAX_ITEMS + 1)) + "]"), "p")


def test_a_file_over_the_size_cap_is_refused_without_being_read(tmp_path):
    huge = tmp_path / "huge.waypoints"
    with open(huge, "wb") as fh:                     # 64 GiB, sparse: reading it whole would not end in time
        fh.write(b"QGC WPL 110\n")
        fh.truncate(64 << 30)
    with pytest.raises(InputError) as e:
        read_mission(huge)
    assert str(e.value) == f"{huge}: expected a mission file of at most {MAX_FILE_BYTES} bytes (1 MiB), got {64 << 30}"
    with pytest.raises(InputError) as e:             # no size beforehand, endless: at most one byte over is read
        read_mission("/dev/zero")
    assert str(e.value) == f"/dev/zero: expected a mission file of at most {MAX_FILE_BYTES} bytes (1 MiB), got more"
    at_cap = tmp_path / "cap.waypoints"
    at_cap.write_bytes(b"QGC WPL 110\n" + b"#" * (MAX_FILE_BYTES - 13) + b"\n")
    assert read_mission(at_cap).items == []


def _plan(items='[]', extra=''):
    return '{"fileType": "Plan", "mission": {"items": %s%s}}' % (items, extra)


SIMPLE = '{"type": "SimpleItem", "command": 16, "frame": 3, "autoContinue": true, "params": [0,0,0,0,1,2,3]}'


@pytest.mark.parametrize("text, message", [
    ("{", "line 1: not valid JSON (Expecting property name enclosed in double quotes)"),
    ("[]", "expected a JSON object (a QGC .plan), got list"),
    ('{"fileType": "Mission"}', 'fileType: expected "Plan", got "Mission"'),
    ('{"fileType": "Plan"}', "mission: expected an object"),
    (_plan('{}'), "mission.items: expected a list"),
    (_plan(f'[{SIMPLE}, {SIMPLE}, {SIMPLE}, {{"type": "ComplexItem", "complexItemType": "survey"}}]'),
     'mission.items[3]: ComplexItem "survey" is not supported; expected a SimpleItem (split it into '
     'waypoints in QGC)'),
    (_plan(f'[{SIMPLE.replace("[0,0,0,0,1,2,3]", "[0,0,0,1,2,3]")}]'),
     "mission.items[0].params: expected 7 numbers or nulls"),
    (_plan(f'[{SIMPLE.replace("[0,0,0,0,1,2,3]", "[0,0,0,true,1,2,3]")}]'),
     "mission.items[0].params: expected 7 numbers or nulls"),
    (_plan(f'[{SIMPLE.replace("16", "16.5")}]'),
     "mission.items[0].command: expected an integer 0..65535, got 16.5"),
    (_plan(f'[{SIMPLE.replace("true", "1")}]'),
     "mission.items[0].autoContinue: expected true or false, got 1"),
    (_plan(f'[{SIMPLE.replace("[0,0,0,0,1,2,3]", "[0,0,0,0,100,2,3]")}]'),
     "mission.items[0].params[4]: expected a latitude in -90..90, got 100.0"),
    (_plan(f'[{SIMPLE.replace("16", "177")}]'), "mission.items[0].params[0]: DO_JUMP to doJumpId 0, "
                                                  "which no item has"),
    (_plan('[]', ', "plannedHomePosition": [1, 2]'),
     "mission.plannedHomePosition: expected [lat, lon, alt] numbers"),
])
def test_plan_errors_are_one_line_naming_file_and_key(text, message):
    with pytest.raises(InputError) as e:
        parse_plan(text, "plan.json")
    assert str(e.value) == f"plan.json: {message}"


def test_unreadable_files(tmp_path):
    with pytest.raises(InputError, match=r"nope.plan: mission file not found$"):
        read_mission(tmp_path / "nope.plan")
    (tmp_path / "bin.txt").write_bytes(b"QGC WPL 110\n\xff\xfe")
    with pytest.raises(InputError, match=r"bin.txt: expected UTF-8 text, got byte 0xff at offset 12$"):
        read_mission(tmp_path / "bin.txt")
    with pytest.raises(InputError, match="cannot write mission file"):
        write_wpl(MIXED, tmp_path)                       # a directory


# ------------------------------------------------------------------------------------------ random input

def _parses_or_input_error(text: str) -> None:
    for parse in (parse_wpl, parse_plan):
        try:
            mf = parse(text, "f")
        except InputError as e:
            assert "\n" not in str(e) and str(e).startswith("f: ")
        else:
            assert all(isinstance(it, MissionItem) and it.check_encodable() is None for it in mf.items)


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=400))
def test_random_text_gives_items_or_input_error(text):
    _parses_or_input_error(text)
    _parses_or_input_error("QGC WPL 110\n" + text)


@settings(max_examples=200, deadline=None)
@given(st.sampled_from([WPL, PLAN]), st.data())
def test_truncated_and_bit_flipped_files(path, data):
    raw = bytearray(path.read_bytes())
    for _ in range(data.draw(st.integers(0, 6))):
        i = data.draw(st.integers(0, len(raw) - 1))
        raw[i] ^= 1 << data.draw(st.integers(0, 7))
    raw = raw[:data.draw(st.integers(0, len(raw)))]
    fd, name = tempfile.mkstemp(suffix=path.suffix)
    try:
        os.write(fd, raw)
        os.close(fd)
        try:
            mf = read_mission(name)
        except InputError as e:
            assert "\n" not in str(e) and str(e).startswith(name)
        else:
            assert all(it.check_encodable() is None for it in mf.items)
    finally:
        os.unlink(name)


@settings(max_examples=200, deadline=None)
@given(st.data())
def test_lines_lost_from_a_wpl_file_are_refused_unless_they_were_its_last(data):
    """WPL has no item count: losing the last lines leaves a shorter mission (the items before them, unchanged);
    losing any other data line breaks the INDEX sequence and is refused naming the line after the gap."""
    lines = WPL.read_text().splitlines()
    whole = parse_wpl("\n".join(lines)).items
    lost = data.draw(st.sets(st.integers(1, len(lines) - 1), min_size=1))
    kept = [line for i, line in enumerate(lines) if i not in lost]
    text = "\n".join(kept) + "\n"
    rest = lost - {1}            # the home line (1) may go: the items' INDEX then starts at 1, as a file without one
    if not rest or rest == set(range(min(rest), len(lines))):            # nothing more, or the last lines
        assert parse_wpl(text).items == whole[:min(rest) - 2 if rest else len(whole)]
        return
    with pytest.raises(InputError, match=r"^f: line \d+: INDEX: expected "):
        parse_wpl(text, "f")
