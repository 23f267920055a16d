"""CiA 402 protocol facts: the drive state machine against the controlword/statusword tables (as canopen's
State402 decodes them), units, INTEGER32 wrap, the object dictionary, and frame classification."""
from __future__ import annotations

import math

import pytest
from canopen.profiles.p402 import State402
from hypothesis import given, strategies as st

from runtime.drivers import cia402_protocol as P
from runtime.errors import InputError


def sequence(cws, drive=None):
    drive = drive or P.Drive402()
    out = []
    for cw in cws:
        drive.command(cw)
        out.append(drive.statusword())
    return drive, out


# ----------------------------------------------------------------------------- state machine
def test_controlword_sequence_06_07_0f_gets_the_statusword_answers():
    """Facts file: Shutdown 0x06 -> Switch on 0x07 -> Enable 0x0F; statusword masks RTSO (0x6F, 0x21),
    SO (0x6F, 0x23), OE (0x6F, 0x27); power-up state SOD (0x4F, 0x40)."""
    drive = P.Drive402()
    assert drive.statusword() & 0x4F == 0x40
    drive, words = sequence([0x06, 0x07, 0x0F], drive)
    assert [w & 0x6F for w in words] == [0x21, 0x23, 0x27]
    assert [P.state_of(w) for w in words] == ["READY TO SWITCH ON", "SWITCHED ON", "OPERATION ENABLED"]
    assert drive.enabled


@pytest.mark.parametrize("start_cws, cw, expected", [
    ([0x06], 0x00, "SWITCH ON DISABLED"),              # 7: disable voltage
    ([0x06], 0x02, "SWITCH ON DISABLED"),              # 7: quick stop from ready
    ([0x06, 0x07], 0x06, "READY TO SWITCH ON"),        # 6
    ([0x06, 0x07], 0x00, "SWITCH ON DISABLED"),        # 10
    ([0x06, 0x07, 0x0F], 0x07, "SWITCHED ON"),         # 5: disable operation
    ([0x06, 0x07, 0x0F], 0x06, "READY TO SWITCH ON"),  # 8
    ([0x06, 0x07, 0x0F], 0x00, "SWITCH ON DISABLED"),  # 9
    ([0x06, 0x07, 0x0F], 0x02, "QUICK STOP ACTIVE"),   # 11
    ([0x06, 0x07, 0x0F, 0x02], 0x0F, "OPERATION ENABLED"),   # 16
    ([0x06, 0x07, 0x0F, 0x02], 0x00, "SWITCH ON DISABLED"),  # 12
    ([0x06], 0x0F, "OPERATION ENABLED"),               # 3 + 4: switch on and enable at once
    ([], 0x07, "SWITCH ON DISABLED"),                  # no transition 2 -> 3 skipping
    ([], 0x0F, "SWITCH ON DISABLED"),
])
def test_transitions(start_cws, cw, expected):
    drive, _ = sequence(start_cws)
    drive.command(cw)
    assert drive.state == expected
    assert P.state_of(drive.statusword()) == expected


def test_every_library_transition_is_taken_by_the_drive():
    """canopen's own TRANSITIONTABLE (what BaseNode402 sends) leads the drive where the library expects."""
    reach = {"SWITCH ON DISABLED": [], "READY TO SWITCH ON": [0x06], "SWITCHED ON": [0x06, 0x07],
             "OPERATION ENABLED": [0x06, 0x07, 0x0F], "QUICK STOP ACTIVE": [0x06, 0x07, 0x0F, 0x02]}
    checked = 0
    for (src, dst), cw in State402.TRANSITIONTABLE.items():
        if src not in reach or dst not in reach:
            continue
        drive, _ = sequence(reach[src])
        drive.command(cw)
        assert drive.state == dst, (src, dst, hex(cw))
        checked += 1
    assert checked >= 12


def test_fault_reaction_fault_and_reset_on_the_rising_edge_of_bit_7():
    drive, _ = sequence([0x06, 0x07, 0x0F])
    assert drive.fault() and not drive.fault()
    assert P.state_of(drive.statusword()) == "FAULT REACTION ACTIVE" and drive.stopping
    drive.command(0x0F)                          # commands are ignored while reacting
    assert drive.state == P.FAULT_REACTION
    drive.reaction_done()
    assert drive.statusword() & 0x4F == 0x08
    drive.command(0x0F)
    assert drive.state == P.FAULT
    drive.command(0x80)                          # 15: fault reset
    assert drive.state == P.SWITCH_ON_DISABLED
    drive.fault()
    drive.reaction_done()
    drive.command(0x80)                          # bit 7 still set: no new edge
    assert drive.state == P.FAULT
    drive.command(0x00)
    drive.command(0x80)
    assert drive.state == P.SWITCH_ON_DISABLED


def test_statusword_bits():
    drive, _ = sequence([0x06, 0x07, 0x0F])
    sw = drive.statusword(target_reached=True)
    assert sw & P.SW_REMOTE and sw & P.SW_TARGET_REACHED and sw & 0x10      # remote, target reached, voltage
    assert sw & 0x20                                                       # quick stop bit is active low
    drive.command(0x02)
    assert not drive.statusword() & 0x20


@given(st.lists(st.integers(0, 0xFFFF), max_size=40), st.lists(st.booleans(), max_size=40))
def test_any_controlwords_and_faults_keep_a_state_the_statusword_names(cws, faults):
    drive = P.Drive402()
    for cw, fault in zip(cws, faults + [False] * len(cws)):
        if fault:
            drive.fault()
            drive.reaction_done()
        drive.command(cw)
        assert P.state_of(drive.statusword()) == drive.state


# ----------------------------------------------------------------------------- units and wrap
def test_units_rpm_and_counts():
    u = P.WheelUnits(wheel_radius=0.075, counts_per_rev=4096, gear_ratio=24.0, velocity_unit="rpm")
    wheel_rev_s = 1.0 / (2 * math.pi * 0.075)
    assert u.velocity(1.0) == round(wheel_rev_s * 60 * 24)             # 3056 motor rpm at 1 m/s
    assert u.mps(u.velocity(0.5)) == pytest.approx(0.5, abs=1e-3)
    assert u.metres(4096 * 24) == pytest.approx(2 * math.pi * 0.075)   # one wheel turn
    c = P.WheelUnits(0.075, 4096, 24.0, "counts_per_s")
    assert c.velocity(2 * math.pi * 0.075) == 4096 * 24                 # one wheel turn per second


@pytest.mark.parametrize("kw", [{"wheel_radius": 0}, {"counts_per_rev": -1}, {"gear_ratio": math.nan},
                                {"velocity_unit": "rad/s"}])
def test_bad_units_are_one_line_input_errors(kw):
    args = {"wheel_radius": 0.075, "counts_per_rev": 4096, **kw}
    with pytest.raises(InputError) as info:
        P.WheelUnits(**args)
    assert "\n" not in str(info.value)


@given(st.integers(-2**31, 2**31 - 1), st.integers(-2**30, 2**30))
def test_delta32_across_the_wrap(start, step):
    end = (start + step + 2**31) % 2**32 - 2**31
    assert P.delta32(end, start) == step


# ----------------------------------------------------------------------------- objects
def test_object_dictionary_has_what_the_master_and_the_profile_need():
    od = P.object_dictionary(5)
    for index in (0x1000, 0x1001, 0x1016, 0x1017, 0x1018, 0x6007, 0x603F, 0x6040, 0x6041, 0x6060, 0x6061, 0x6064,
                  0x606C, 0x6083, 0x6084, 0x6085, 0x60FF, 0x6502):
        assert index in od, hex(index)
    for base in (0x1400, 0x1600, 0x1800, 0x1A00):
        assert all(base + n in od for n in range(4))
    assert od[0x1000].default & 0xFFFF == 402
    assert od[0x6502].default & 0x0004                                 # profile velocity supported
    assert od[0x1800][1].default == 0x185 and od[0x1400][1].default == 0x205       # predefined connection set
    assert od[0x1801][1].default == 0x80000285                          # TPDO2 invalid until configured
    assert od[0x1A00][1].default == P.map_entry(0x6041, 0, 16) == 0x60410010


def test_consumer_entry_is_node_id_and_ms():
    assert P.consumer_entry(127, 0.3) == 0x007F012C
    assert P.consumer_entry(1, 100.0) == 0x0001FFFF


# ----------------------------------------------------------------------------- frames
@pytest.mark.parametrize("can_id, data, expected", [
    (0x000, bytes([0x01, 0x01]), ("nmt", 1)),
    (0x000, bytes([0x81, 0x00]), ("nmt", 0)),
    (0x080, b"", ("sync", 0)),
    (0x081, bytes([0x10, 0x23, 0x03, 0, 0, 0, 0, 0]), ("emcy", 1)),
    (0x181, bytes([0x37, 0x02, 0x03]), ("tpdo", 1)),
    (0x201, bytes([0x0F, 0, 0, 0, 0, 0, 3]), ("rpdo", 1)),
    (0x282, bytes(8), ("tpdo", 2)),
    (0x581, bytes(8), ("sdo_tx", 1)),
    (0x602, bytes(8), ("sdo_rx", 2)),
    (0x701, bytes([0x05]), ("heartbeat", 1)),
    (0x77F, bytes([0x7F]), ("heartbeat", 127)),
    (0x701, bytes([0x00]), ("heartbeat", 1)),
])
def test_classify_known_frames(can_id, data, expected):
    assert P.classify(can_id, data) == expected


@pytest.mark.parametrize("can_id, data, extended", [
    (0x000, bytes([0x01]), False),          # NMT needs 2 bytes
    (0x081, bytes(7), False),               # EMCY is 8 bytes
    (0x701, bytes([0x03]), False),          # no NMT state 3
    (0x701, b"", False),
    (0x581, bytes(4), False),
    (0x700, bytes([0x05]), False),          # node id 0
    (0x7E5, bytes(8), False),               # LSS, not a service of this base
    (0x181, bytes(2), True),                # extended
])
def test_classify_rejects_frames_no_service_sends(can_id, data, extended):
    assert P.classify(can_id, data, extended) is None


@given(st.integers(0, 0x1FFFFFFF), st.binary(max_size=12), st.booleans())
def test_classify_never_raises(can_id, data, extended):
    out = P.classify(can_id, data, extended)
    assert out is None or (isinstance(out[0], str) and 0 <= out[1] <= 127)


def test_error_register_classes():
    assert P.error_register(P.EMCY_OVERCURRENT) == 0x03
    assert P.error_register(P.EMCY_HEARTBEAT) == 0x11
    assert P.error_register(P.EMCY_NO_ERROR) == 0
    assert P.error_register(0xFF00) == 0x01
