"""GcsServices: a stock ground station's requests, sent through real pymavlink frames, get their answers."""
from __future__ import annotations

import struct
import tomllib
from pathlib import Path

import pytest
from hypothesis import given, settings, strategies as st
from pymavlink.generator.mavcrc import x25crc

from runtime.comms import dialect, ftp_nack
from runtime.comms.gcs_services import BROADCAST_OK, GcsServices, package_version, sw_version
from runtime.comms.params import Param, ParamTable
from runtime.errors import InputError

mod = dialect.load()
ROBOT, COMP = 3, 1
GCS_SYS, GCS_COMP = 255, 190            # MAVProxy's default source system / component
SRC = ("127.0.0.1", 14550)


class Gcs:
    """Encodes like a ground station and decodes the robot's replies the way it would."""

    def __init__(self, sysid=GCS_SYS, compid=GCS_COMP):
        self.tx = mod.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.robot_mav = mod.MAVLink(None, srcSystem=ROBOT, srcComponent=COMP)

    def wire(self, msg):
        """``msg`` as the robot receives it: packed by the GCS, decoded by a fresh pymavlink parser."""
        rx = mod.MAVLink(None)
        out = rx.parse_buffer(msg.pack(self.tx))
        assert len(out) == 1
        return out[0]

    def seen(self, replies):
        """The robot's replies as the GCS decodes them (pairs from handle/tick)."""
        rx = mod.MAVLink(None)
        out = []
        for msg, source in replies:
            assert source == SRC
            out += rx.parse_buffer(msg.pack(self.robot_mav)) or []
        assert len(out) == len(replies)
        return out


def make_table(n_extra=0):
    values = {"CTL_CRUISE_SPD": 0.5, "ALLOC_RETRIES": 3}
    params = [Param("CTL_CRUISE_SPD", float, 0.0, 2.0, "cruise speed, m/s", lambda: values["CTL_CRUISE_SPD"],
                    lambda v: values.__setitem__("CTL_CRUISE_SPD", v)),
              Param("ALLOC_RETRIES", int, 0, 10, "bid retries", lambda: values["ALLOC_RETRIES"],
                    lambda v: values.__setitem__("ALLOC_RETRIES", v))]
    for i in range(n_extra):
        params.append(Param(f"X_{i:02d}", float, -100, 100, "extra", lambda i=i: float(i), lambda v: None))
    return ParamTable(params), values


@pytest.fixture
def gcs():
    return Gcs()


@pytest.fixture
def svc():
    table, values = make_table()
    s = GcsServices(mod.MAVLink(None, srcSystem=ROBOT, srcComponent=COMP), ROBOT, COMP, table)
    s.values = values
    return s


def ask(svc, gcs, msg, now=0.0):
    return gcs.seen(svc.handle(gcs.wire(msg), now, SRC))


def command(gcs, cmd, *params, target=ROBOT, comp=COMP):
    p = list(params) + [0.0] * (7 - len(params))
    return gcs.tx.command_long_encode(target, comp, cmd, 0, *p)


def drain(svc, gcs, ticks=50):
    out = []
    for k in range(ticks):
        out += gcs.seen(svc.tick(float(k)))
    return out


# ---------------------------------------------------------------------- QGC's connection sequence

def expected_sw_version() -> int:
    text = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())["project"]["version"]
    major, minor, patch = (int(x) for x in text.split("."))
    return (major << 24) | (minor << 16) | (patch << 8) | mod.FIRMWARE_VERSION_TYPE_OFFICIAL


def test_qgc_connection_sequence_is_answered_step_by_step(svc, gcs):
    L = mod
    # 1. REQUEST_MESSAGE(AUTOPILOT_VERSION): ACCEPTED ack first, then the message
    ack, ver = ask(svc, gcs, command(gcs, L.MAV_CMD_REQUEST_MESSAGE, L.MAVLINK_MSG_ID_AUTOPILOT_VERSION))
    assert ack.get_type() == "COMMAND_ACK" and ver.get_type() == "AUTOPILOT_VERSION"
    assert (ack.command, ack.result) == (L.MAV_CMD_REQUEST_MESSAGE, L.MAV_RESULT_ACCEPTED)
    assert (ack.target_system, ack.target_component) == (GCS_SYS, GCS_COMP)
    assert ver.capabilities == (L.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | L.MAV_PROTOCOL_CAPABILITY_MISSION_INT
                                | L.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                                | L.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST)
    assert not ver.capabilities & (L.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE | L.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY
                                   | L.MAV_PROTOCOL_CAPABILITY_FTP | L.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE)
    assert ver.flight_sw_version == expected_sw_version() == 0x000100FF      # 0.1.0 official
    assert (ver.uid, ver.vendor_id, ver.product_id) == (ROBOT, 0, 0)
    assert ver.get_srcSystem() == ROBOT and ver.get_srcComponent() == COMP
    # 2. PROTOCOL_VERSION (older QGC), 3. AVAILABLE_MODES, 4. component information/metadata:
    #    not in the dialect -> UNSUPPORTED at once, nothing else (QGC moves on instead of retrying)
    for msg_id in (300, 435, 395, 397):
        (ack,) = ask(svc, gcs, command(gcs, L.MAV_CMD_REQUEST_MESSAGE, msg_id, 0))
        assert (ack.command, ack.result) == (L.MAV_CMD_REQUEST_MESSAGE, L.MAV_RESULT_UNSUPPORTED)
    # 5. parameters: every PARAM_VALUE once, with a consistent count and index
    assert ask(svc, gcs, gcs.tx.param_request_list_encode(ROBOT, L.MAV_COMP_ID_ALL)) == []
    values = drain(svc, gcs)
    assert [(v.param_id, v.param_index, v.param_count) for v in values] == [("CTL_CRUISE_SPD", 0, 2),
                                                                             ("ALLOC_RETRIES", 1, 2)]
    # 6-8. mission, fence, rally: runtime.comms.mission's (QGC skips fence and rally for want of the bits)
    assert svc.stats.errors == 0 and svc.stats.not_for_us == 0


def test_request_autopilot_capabilities_command(svc, gcs):
    ack, ver = ask(svc, gcs, command(gcs, mod.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1))
    assert (ack.command, ack.result) == (mod.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, mod.MAV_RESULT_ACCEPTED)
    assert ver.get_type() == "AUTOPILOT_VERSION" and ver.uid == ROBOT


def test_version_fields_can_be_overridden_by_name(gcs):
    table, _ = make_table()
    s = GcsServices(mod.MAVLink(None, srcSystem=ROBOT, srcComponent=COMP), ROBOT, COMP, table,
                    {"vendor_id": 0x1234, "flight_custom_version": list(b"abcdef12")})
    ver = gcs.seen([(s.autopilot_version(), SRC)])[0]
    assert ver.vendor_id == 0x1234 and bytes(ver.flight_custom_version) == b"abcdef12"
    with pytest.raises(InputError, match="unknown field 'colour'"):
        GcsServices(mod.MAVLink(None), ROBOT, COMP, table, {"colour": 1})


@pytest.mark.parametrize("text, fields", [
    ("0.1.0", (0, 1, 0, "OFFICIAL")), ("2.3", (2, 3, 0, "OFFICIAL")), ("1.2.3rc1", (1, 2, 3, "RC")),
    ("1.2.3b2", (1, 2, 3, "BETA")), ("1.2.3a1", (1, 2, 3, "ALPHA")), ("1.2.3.dev4", (1, 2, 3, "DEV")),
    ("1.2.3+local", (1, 2, 3, "DEV")), ("1.2.3.post1", (1, 2, 3, "OFFICIAL")), ("300.2.1", (255, 2, 1, "OFFICIAL")),
])
def test_sw_version_bytes_read_as_qgc_reads_them(text, fields):
    v = sw_version(text, mod)
    # InitialConnectStateMachine: major = v >> 24, minor = v >> 16, patch = v >> 8, type = v & 0xff
    got = ((v >> 24) & 0xFF, (v >> 16) & 0xFF, (v >> 8) & 0xFF, v & 0xFF)
    assert got == fields[:3] + (getattr(mod, "FIRMWARE_VERSION_TYPE_" + fields[3]),)
    assert sw_version("not a version", mod) == 0 and sw_version(None, mod) == 0


def test_the_installed_package_version_is_the_projects():
    assert package_version() == tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())[
        "project"]["version"]


# ---------------------------------------------------------------------- parameters

def cast_reads(m) -> float:
    """How MAVSDK (ParamValue::set_from_mavlink_param_value_cast), QGC's APM plugin and MAVProxy
    (handle_px4_param_value for a non-PX4 autopilot) read a PARAM_VALUE of an ArduPilot vehicle: the number,
    converted to the declared type."""
    conv = {mod.MAV_PARAM_TYPE_REAL32: float, mod.MAV_PARAM_TYPE_INT32: int}[m.param_type]
    return conv(m.param_value)


def bytewise_reads(m) -> float:
    """QGC's (and MAVSDK's) reading for a vehicle that is not ArduPilot: the float's bytes as the declared type."""
    raw = struct.pack("<f", m.param_value)
    fmt = {mod.MAV_PARAM_TYPE_REAL32: "<f", mod.MAV_PARAM_TYPE_INT32: "<i"}[m.param_type]
    return struct.unpack(fmt, raw)[0]


def test_integers_travel_as_int32_c_cast_and_every_stock_gcs_reads_them(svc, gcs):
    svc.values.update(CTL_CRUISE_SPD=1.75, ALLOC_RETRIES=7)
    ask(svc, gcs, gcs.tx.param_request_list_encode(ROBOT, 0))
    values = {v.param_id: v for v in drain(svc, gcs)}
    assert values["CTL_CRUISE_SPD"].param_type == mod.MAV_PARAM_TYPE_REAL32
    assert values["ALLOC_RETRIES"].param_type == mod.MAV_PARAM_TYPE_INT32      # MAVSDK get_param_int needs it
    for name, want in (("CTL_CRUISE_SPD", 1.75), ("ALLOC_RETRIES", 7)):
        assert cast_reads(values[name]) == want
    assert values["ALLOC_RETRIES"].param_value == 7.0                        # C-cast, not the bytes of int 7
    assert bytewise_reads(values["ALLOC_RETRIES"]) != 7                      # why the autopilot must say ArduPilot
    (v,) = ask(svc, gcs, gcs.tx.param_set_encode(ROBOT, COMP, b"ALLOC_RETRIES", 4.0, mod.MAV_PARAM_TYPE_INT32))
    assert svc.values["ALLOC_RETRIES"] == 4 and cast_reads(v) == 4 and v.param_type == mod.MAV_PARAM_TYPE_INT32


def test_a_long_list_is_spread_over_ticks(gcs):
    table, _ = make_table(n_extra=23)
    s = GcsServices(mod.MAVLink(None, srcSystem=ROBOT, srcComponent=COMP), ROBOT, COMP, table, params_per_tick=10)
    s.handle(gcs.wire(gcs.tx.param_request_list_encode(ROBOT, 0)), 0.0, SRC)
    per_tick = [gcs.seen(s.tick(t)) for t in (0.1, 0.2, 0.3, 0.4)]
    assert [len(b) for b in per_tick] == [10, 10, 5, 0]
    got = [v for b in per_tick for v in b]
    assert [v.param_index for v in got] == list(range(25))
    assert {v.param_count for v in got} == {25}
    assert [v.param_id for v in got[2:4]] == ["X_00", "X_01"] and got[3].param_value == 1.0


def test_a_new_list_request_restarts_and_two_sources_both_get_the_list(gcs):
    table, _ = make_table(n_extra=8)                   # 10 parameters
    s = GcsServices(mod.MAVLink(None, srcSystem=ROBOT, srcComponent=COMP), ROBOT, COMP, table, params_per_tick=4)
    req = gcs.wire(gcs.tx.param_request_list_encode(ROBOT, 0))
    s.handle(req, 0.0, "a")
    assert [m.param_index for m, _ in s.tick(0.1)] == [0, 1, 2, 3]
    s.handle(req, 0.2, "a")                             # e.g. a retry: start again
    s.handle(req, 0.2, "b")
    sent = []
    for t in range(10):
        sent += [(src, m.param_index) for m, src in s.tick(0.3 + t)]
    assert [i for src, i in sent if src == "a"] == list(range(10))
    assert [i for src, i in sent if src == "b"] == list(range(10))


def test_no_parameters_means_no_reply(gcs):
    s = GcsServices(mod.MAVLink(None, srcSystem=ROBOT, srcComponent=COMP), ROBOT, COMP, ParamTable())
    assert s.handle(gcs.wire(gcs.tx.param_request_list_encode(ROBOT, 0)), 0.0, SRC) == []
    assert s.tick(0.1) == [] and s.stats.served == 1


def test_read_by_name_by_index_and_unknown(svc, gcs):
    (v,) = ask(svc, gcs, gcs.tx.param_request_read_encode(ROBOT, COMP, b"ALLOC_RETRIES", -1))
    assert (v.param_id, v.param_value, v.param_index, v.param_count) == ("ALLOC_RETRIES", 3.0, 1, 2)
    (v,) = ask(svc, gcs, gcs.tx.param_request_read_encode(ROBOT, COMP, b"IGNORED_NAME", 0))
    assert v.param_id == "CTL_CRUISE_SPD"
    for name, index, says in ((b"NO_SUCH", -1, "'NO_SUCH'"), (b"", 9, "index 9")):
        (t,) = ask(svc, gcs, gcs.tx.param_request_read_encode(ROBOT, COMP, name, index))
        assert t.get_type() == "STATUSTEXT" and says in t.text          # the spec's advice; no PARAM_VALUE
    assert svc.stats.param_unknown == 2


def test_param_set_in_range_applies_and_echoes_the_new_value(svc, gcs):
    (v,) = ask(svc, gcs, gcs.tx.param_set_encode(ROBOT, COMP, b"CTL_CRUISE_SPD", 1.5, mod.MAV_PARAM_TYPE_REAL32))
    assert svc.values["CTL_CRUISE_SPD"] == 1.5
    assert (v.param_id, v.param_value, v.param_index, v.param_count) == ("CTL_CRUISE_SPD", 1.5, 0, 2)
    (v,) = ask(svc, gcs, gcs.tx.param_set_encode(ROBOT, COMP, b"ALLOC_RETRIES", 9.0, mod.MAV_PARAM_TYPE_REAL32))
    assert svc.values["ALLOC_RETRIES"] == 9 and v.param_value == 9.0


@pytest.mark.parametrize("name, value, says", [
    (b"CTL_CRUISE_SPD", 5.0, "out of range 0..2"),
    (b"CTL_CRUISE_SPD", float("nan"), "finite"),
    (b"ALLOC_RETRIES", 2.5, "integer"),
])
def test_param_set_refused_echoes_the_unchanged_value_and_says_why(svc, gcs, name, value, says):
    before = dict(svc.values)
    v, t = ask(svc, gcs, gcs.tx.param_set_encode(ROBOT, COMP, name, value, mod.MAV_PARAM_TYPE_REAL32))
    assert svc.values == before
    assert v.get_type() == "PARAM_VALUE" and v.param_value == before[name.decode()]
    assert t.get_type() == "STATUSTEXT" and says in t.text and t.severity == mod.MAV_SEVERITY_WARNING
    assert svc.stats.param_sets_refused == 1


def test_param_set_of_an_unknown_name(svc, gcs):
    (t,) = ask(svc, gcs, gcs.tx.param_set_encode(ROBOT, COMP, b"NO_SUCH", 1.0, mod.MAV_PARAM_TYPE_REAL32))
    assert t.get_type() == "STATUSTEXT" and "NO_SUCH" in t.text and svc.stats.param_unknown == 1


# ---------------------------------------------------------------------- commands

def test_unknown_commands_get_unsupported_acks(svc, gcs):
    for msg in (command(gcs, mod.MAV_CMD_DO_SET_MODE, 1, 4),
                command(gcs, mod.MAV_CMD_COMPONENT_ARM_DISARM, 1),
                gcs.tx.command_int_encode(ROBOT, COMP, 0, mod.MAV_CMD_DO_REPOSITION, 0, 0, 0, 0, 0, 0, 1, 2, 3.0)):
        (ack,) = ask(svc, gcs, msg)
        assert ack.get_type() == "COMMAND_ACK" and ack.result == mod.MAV_RESULT_UNSUPPORTED
        assert ack.command == msg.command and (ack.target_system, ack.target_component) == (GCS_SYS, GCS_COMP)
    assert svc.stats.commands_unsupported == 3 == svc.stats.command_acks


def test_registered_commands_are_dispatched_with_msg_and_now(svc, gcs):
    calls = []

    def arm(msg, now):
        calls.append((msg.get_type(), msg.param1, now))
        return mod.MAV_RESULT_ACCEPTED if msg.param1 in (0.0, 1.0) else mod.MAV_RESULT_DENIED

    svc.register_command(mod.MAV_CMD_COMPONENT_ARM_DISARM, arm)
    (ack,) = ask(svc, gcs, command(gcs, mod.MAV_CMD_COMPONENT_ARM_DISARM, 0), now=12.5)
    assert ack.result == mod.MAV_RESULT_ACCEPTED and calls == [("COMMAND_LONG", 0.0, 12.5)]
    (ack,) = ask(svc, gcs, gcs.tx.command_int_encode(ROBOT, COMP, 0, mod.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0,
                                                     7, 0, 0, 0, 0, 0, 0.0), now=13.0)
    assert ack.result == mod.MAV_RESULT_DENIED and calls[-1] == ("COMMAND_INT", 7.0, 13.0)


@pytest.mark.parametrize("handler", [lambda msg, now: 1 / 0, lambda msg, now: None, lambda msg, now: 99,
                                     lambda msg, now: True])
def test_a_failing_or_wrong_handler_is_acked_failed(svc, gcs, handler):
    svc.register_command(31000, handler)
    (ack,) = ask(svc, gcs, command(gcs, 31000))
    assert (ack.command, ack.result) == (31000, mod.MAV_RESULT_FAILED)


def test_built_in_commands_cannot_be_replaced(svc):
    for cmd in (mod.MAV_CMD_REQUEST_MESSAGE, mod.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, mod.MAV_CMD_GET_HOME_POSITION):
        with pytest.raises(ValueError):
            svc.register_command(cmd, lambda msg, now: 0)
    with pytest.raises(ValueError):
        svc.register_message(mod.MAVLINK_MSG_ID_AUTOPILOT_VERSION, lambda: None)


def test_request_message_goes_to_the_providers(svc, gcs):
    home = svc.mav.home_position_encode(1, 2, 3, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0)
    svc.register_message(mod.MAVLINK_MSG_ID_HOME_POSITION, lambda: home)
    svc.register_message(mod.MAVLINK_MSG_ID_GPS_RAW_INT, lambda: None)         # nothing yet
    svc.register_message(mod.MAVLINK_MSG_ID_BATTERY_STATUS, lambda: 1 / 0)
    ack, msg = ask(svc, gcs, command(gcs, mod.MAV_CMD_REQUEST_MESSAGE, mod.MAVLINK_MSG_ID_HOME_POSITION))
    assert ack.result == mod.MAV_RESULT_ACCEPTED and msg.get_type() == "HOME_POSITION" and msg.latitude == 1
    for msg_id, result in ((mod.MAVLINK_MSG_ID_GPS_RAW_INT, mod.MAV_RESULT_TEMPORARILY_REJECTED),
                           (mod.MAVLINK_MSG_ID_BATTERY_STATUS, mod.MAV_RESULT_FAILED),
                           (mod.MAVLINK_MSG_ID_ATTITUDE, mod.MAV_RESULT_UNSUPPORTED),
                           (float("nan"), mod.MAV_RESULT_DENIED), (-1.0, mod.MAV_RESULT_DENIED),
                           (148.5, mod.MAV_RESULT_DENIED)):
        (ack,) = ask(svc, gcs, command(gcs, mod.MAV_CMD_REQUEST_MESSAGE, msg_id))
        assert ack.result == result, msg_id


def test_mavproxys_get_home_position_uses_the_home_position_provider(svc, gcs):
    (ack,) = ask(svc, gcs, command(gcs, mod.MAV_CMD_GET_HOME_POSITION))
    assert (ack.command, ack.result) == (mod.MAV_CMD_GET_HOME_POSITION, mod.MAV_RESULT_UNSUPPORTED)
    home = svc.mav.home_position_encode(7, 8, 9, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0)
    svc.register_message(mod.MAVLINK_MSG_ID_HOME_POSITION, lambda: home)
    ack, msg = ask(svc, gcs, command(gcs, mod.MAV_CMD_GET_HOME_POSITION))
    assert ack.result == mod.MAV_RESULT_ACCEPTED and (msg.latitude, msg.longitude) == (7, 8)


# ---------------------------------------------------------------------- mission: not ours

def test_mission_messages_are_left_to_the_mission_server(svc, gcs):
    for msg in (gcs.tx.mission_request_list_encode(ROBOT, COMP, 0), gcs.tx.mission_count_encode(ROBOT, COMP, 3, 0),
                gcs.tx.mission_clear_all_encode(ROBOT, COMP, 0)):
        assert ask(svc, gcs, msg) == []
    assert svc.stats.ignored == 3 and svc.stats.served == 0


# ---------------------------------------------------------------------- FTP

def mavproxy_ftp_request(seq, session, opcode, name: bytes = b""):
    """MAVProxy FTP_OP.pack + FTPModule.send: header "<HBBBBBBI", data, zero padded to 251 bytes."""
    raw = struct.pack("<HBBBBBBI", seq, session, opcode, len(name), 0, 0, 0, 0) + name
    return list(raw.ljust(251, b"\0"))


def mavproxy_op_parse(m):
    """MAVProxy FTPModule.op_parse."""
    seq, session, opcode, size, req_opcode, burst, _pad, offset = struct.unpack("<HBBBBBBI", bytearray(m.payload[0:12]))
    return seq, session, opcode, size, req_opcode, burst, offset, bytearray(m.payload[12:])[:size]


def test_ftp_param_download_is_refused_at_once_the_way_mavproxy_checks(svc, gcs):
    name = b"@PARAM/param.pck?withdefaults=1"
    req = gcs.tx.file_transfer_protocol_encode(0, ROBOT, COMP, mavproxy_ftp_request(41, 0, 4, name))
    (reply,) = ask(svc, gcs, req)
    assert reply.get_type() == "FILE_TRANSFER_PROTOCOL"
    # mavproxy_ftp.mavlink_packet drops replies not addressed to its own source system AND component
    assert (reply.target_system, reply.target_component) == (GCS_SYS, GCS_COMP)
    seq, session, opcode, size, req_opcode, burst, offset, data = mavproxy_op_parse(reply)
    assert (opcode, req_opcode, size, data[0]) == (129, 4, 1, 10)       # NAK to OpenFileRO: FileNotFound
    assert (seq, session, burst, offset) == (42, 0, 0, 0)
    assert svc.stats.ftp_replies == 1


@pytest.mark.parametrize("opcode, reply, size, err", [
    (0, 128, 0, None), (2, 128, 0, None),                    # None, ResetSessions: ACK
    (1, 129, 1, 4), (5, 129, 1, 4), (15, 129, 1, 4),        # session ops: InvalidSession
    (3, 129, 1, 10), (14, 129, 1, 10),                      # list, CRC: FileNotFound
    (6, 129, 1, 9), (11, 129, 1, 9),                        # create, open for write: FileProtected
    (77, 129, 1, 7),                                        # UnknownCommand
])
def test_ftp_answers_by_opcode(svc, gcs, opcode, reply, size, err):
    (r,) = ask(svc, gcs, gcs.tx.file_transfer_protocol_encode(0, ROBOT, COMP, mavproxy_ftp_request(65535, 7, opcode)))
    seq, session, op, sz, req_op, _b, _o, data = mavproxy_op_parse(r)
    assert (seq, session, op, sz, req_op) == (0, 7, reply, size, opcode)
    assert (data[0] if err is not None else None) == err


def test_ftp_replies_are_never_answered_and_constants_match_the_dialect(svc, gcs):
    for opcode in (128, 129):
        assert ask(svc, gcs, gcs.tx.file_transfer_protocol_encode(0, ROBOT, COMP, mavproxy_ftp_request(1, 0, opcode))) == []
    for ours, theirs in ((ftp_nack.OP_NAK, "MAV_FTP_OPCODE_NAK"), (ftp_nack.OP_ACK, "MAV_FTP_OPCODE_ACK"),
                         (ftp_nack.OP_OPEN_FILE_RO, "MAV_FTP_OPCODE_OPENFILERO"),
                         (ftp_nack.OP_TERMINATE_SESSION, "MAV_FTP_OPCODE_TERMINATESESSION"),
                         (ftp_nack.OP_RESET_SESSIONS, "MAV_FTP_OPCODE_RESETSESSION"),
                         (ftp_nack.OP_BURST_READ_FILE, "MAV_FTP_OPCODE_BURSTREADFILE"),
                         (ftp_nack.ERR_FILE_NOT_FOUND, "MAV_FTP_ERR_FILENOTFOUND"),
                         (ftp_nack.ERR_INVALID_SESSION, "MAV_FTP_ERR_INVALIDSESSION"),
                         (ftp_nack.ERR_FILE_PROTECTED, "MAV_FTP_ERR_FILEPROTECTED"),
                         (ftp_nack.ERR_UNKNOWN_COMMAND, "MAV_FTP_ERR_UNKNOWNCOMMAND")):
        assert ours == getattr(mod, theirs)
    assert ftp_nack.parse([1, 2, 3]) is None and ftp_nack.parse(None) is None


# ---------------------------------------------------------------------- addressing

def test_messages_for_another_system_or_component_are_ignored_and_counted(svc, gcs):
    others = [command(gcs, mod.MAV_CMD_REQUEST_MESSAGE, 148, target=4),
              command(gcs, mod.MAV_CMD_REQUEST_MESSAGE, 148, comp=50),
              gcs.tx.param_request_list_encode(7, 0),
              gcs.tx.param_set_encode(0, 0, b"CTL_CRUISE_SPD", 1.0, 9),     # a SET must name the robot
              gcs.tx.file_transfer_protocol_encode(0, 0, COMP, mavproxy_ftp_request(1, 0, 4, b"x"))]
    for msg in others:
        assert ask(svc, gcs, msg) == []
    assert svc.stats.not_for_us == len(others) and svc.stats.served == 0
    assert svc.values["CTL_CRUISE_SPD"] == 0.5
    svc.handle(gcs.wire(gcs.tx.heartbeat_encode(6, 8, 0, 0, 0)), 0.0, SRC)
    assert svc.stats.ignored == 1


def test_broadcast_requests_are_served(svc, gcs):
    ack, _ = ask(svc, gcs, command(gcs, mod.MAV_CMD_REQUEST_MESSAGE, 148, target=0, comp=0))
    assert ack.result == mod.MAV_RESULT_ACCEPTED
    (v,) = ask(svc, gcs, gcs.tx.param_request_read_encode(0, 0, b"ALLOC_RETRIES", -1))
    assert v.param_id == "ALLOC_RETRIES"
    assert "PARAM_SET" not in BROADCAST_OK and "FILE_TRANSFER_PROTOCOL" not in BROADCAST_OK


# ---------------------------------------------------------------------- never raises (property tests)

FUZZ = settings(max_examples=300, deadline=None)
SERVED = ["COMMAND_LONG", "COMMAND_INT", "PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET",
          "FILE_TRANSFER_PROTOCOL"]
IDS = [getattr(mod, "MAVLINK_MSG_ID_" + name) for name in SERVED]


def frame(msg_id: int, payload: bytes, seq=0, sysid=GCS_SYS, compid=GCS_COMP) -> bytes:
    """A MAVLink 2 frame with a correct CRC around any payload bytes."""
    hdr = bytes([len(payload), 0, 0, seq, sysid, compid]) + struct.pack("<I", msg_id)[:3]
    crc = x25crc(hdr + payload)
    crc.accumulate([mod.mavlink_map[msg_id].crc_extra])
    return b"\xfd" + hdr + payload + struct.pack("<H", crc.crc)


def feed(svc, data: bytes) -> int:
    """Parse ``data`` as a GCS datagram and hand every decoded message to handle(); returns how many."""
    rx = mod.MAVLink(None)
    rx.robust_parsing = True
    try:
        msgs = rx.parse_buffer(data) or []
    except Exception:           # pymavlink itself may raise on some inputs: not ours to test
        return 0
    for m in msgs:
        svc.handle(m, 1.0, SRC)
    svc.tick(1.0)
    return len(msgs)


def fresh():
    table, _ = make_table(n_extra=3)
    s = GcsServices(mod.MAVLink(None, srcSystem=ROBOT, srcComponent=COMP), ROBOT, COMP, table, params_per_tick=2)
    s.register_command(mod.MAV_CMD_COMPONENT_ARM_DISARM, lambda msg, now: mod.MAV_RESULT_ACCEPTED)
    s.register_message(mod.MAVLINK_MSG_ID_ATTITUDE, lambda: None)
    return s


def balanced(s) -> bool:
    st_ = s.stats
    return st_.received == st_.served + st_.not_for_us + st_.ignored + st_.errors


@FUZZ
@given(st.binary(min_size=1, max_size=400))
def test_random_datagrams_never_raise(data):
    s = fresh()
    n = feed(s, data)
    assert s.stats.received == n and balanced(s)


@FUZZ
@given(st.sampled_from(IDS), st.binary(min_size=0, max_size=255))
def test_frames_of_served_types_with_random_payloads_never_raise(msg_id, payload):
    """Valid CRC, arbitrary field values: each decoded one reaches handle() and is accounted for."""
    s = fresh()
    n = feed(s, frame(msg_id, payload))
    assert s.stats.received == n and balanced(s)


def real_frames(gcs):
    tx = gcs.tx
    msgs = [command(gcs, mod.MAV_CMD_REQUEST_MESSAGE, 148), command(gcs, mod.MAV_CMD_COMPONENT_ARM_DISARM, 1),
            tx.command_int_encode(ROBOT, COMP, 0, 512, 0, 0, 148, 0, 0, 0, 0, 0, 0.0),
            tx.param_request_list_encode(ROBOT, 0), tx.param_request_read_encode(ROBOT, 0, b"ALLOC_RETRIES", -1),
            tx.param_set_encode(ROBOT, COMP, b"CTL_CRUISE_SPD", 1.0, 9),
            tx.file_transfer_protocol_encode(0, ROBOT, COMP, mavproxy_ftp_request(3, 0, 4, b"@PARAM/param.pck"))]
    return [m.pack(tx) for m in msgs]


REAL = real_frames(Gcs())


@FUZZ
@given(st.sampled_from(REAL), st.data())
def test_bit_flipped_frames_never_raise(raw, data):
    """Flips anywhere (mostly CRC failures), and flips inside the payload with the CRC made good again
    (the frame decodes, its fields are garbage)."""
    s = fresh()
    buf = bytearray(raw)
    for _ in range(data.draw(st.integers(1, 4))):
        bit = data.draw(st.integers(0, len(buf) * 8 - 1))
        buf[bit // 8] ^= 1 << (bit % 8)
    n = feed(s, bytes(buf))
    length, msg_id = raw[1], int.from_bytes(raw[7:10], "little")
    payload = bytearray(raw[10:10 + length])
    for _ in range(data.draw(st.integers(1, 8))):
        bit = data.draw(st.integers(0, len(payload) * 8 - 1))
        payload[bit // 8] ^= 1 << (bit % 8)
    n += feed(s, frame(msg_id, bytes(payload)))
    assert s.stats.received == n and balanced(s)


@FUZZ
@given(st.sampled_from(REAL), st.data())
def test_truncated_frames_never_raise(raw, data):
    s = fresh()
    cut = data.draw(st.integers(1, len(raw) - 1))
    n = feed(s, raw[:cut])
    assert n == 0 and s.stats.received == 0


def test_handle_survives_a_message_whose_fields_will_not_convert(svc, gcs):
    msg = gcs.wire(command(gcs, mod.MAV_CMD_REQUEST_MESSAGE, 148))
    msg.target_system = "junk"
    assert svc.handle(msg, 0.0, SRC) == [] and svc.stats.errors == 1 and balanced(svc)


F32 = st.floats(width=32)                     # NaN and +-inf included
U8, U16 = st.integers(0, 255), st.integers(0, 65535)
NAME = st.binary(max_size=16)
TARGET, COMPONENT = st.sampled_from([ROBOT, 0]), st.sampled_from([COMP, 0])
BUILD = {
    "COMMAND_LONG": lambda tx, d: tx.command_long_encode(
        d.draw(TARGET), d.draw(COMPONENT), d.draw(st.sampled_from([512, 520, 400, 176]) | U16), d.draw(U8),
        *[d.draw(F32) for _ in range(7)]),
    "COMMAND_INT": lambda tx, d: tx.command_int_encode(
        d.draw(TARGET), d.draw(COMPONENT), d.draw(U8), d.draw(st.sampled_from([512, 400]) | U16), d.draw(U8),
        d.draw(U8), *[d.draw(F32) for _ in range(4)], d.draw(st.integers(-2**31, 2**31 - 1)),
        d.draw(st.integers(-2**31, 2**31 - 1)), d.draw(F32)),
    "PARAM_REQUEST_LIST": lambda tx, d: tx.param_request_list_encode(d.draw(TARGET), d.draw(COMPONENT)),
    "PARAM_REQUEST_READ": lambda tx, d: tx.param_request_read_encode(
        d.draw(TARGET), d.draw(COMPONENT), d.draw(NAME | st.sampled_from([b"ALLOC_RETRIES", b"X_01"])),
        d.draw(st.integers(-32768, 32767))),
    "PARAM_SET": lambda tx, d: tx.param_set_encode(
        ROBOT, d.draw(COMPONENT), d.draw(NAME | st.sampled_from([b"ALLOC_RETRIES", b"CTL_CRUISE_SPD"])),
        d.draw(F32), d.draw(U8)),
    "FILE_TRANSFER_PROTOCOL": lambda tx, d: tx.file_transfer_protocol_encode(
        d.draw(U8), ROBOT, d.draw(COMPONENT), list(d.draw(st.binary(min_size=251, max_size=251)))),
}


@FUZZ
@given(st.sampled_from(sorted(BUILD)), st.data())
def test_any_field_values_addressed_to_us_are_served_without_raising(kind, data):
    gcs = Gcs(sysid=data.draw(st.integers(1, 255)), compid=data.draw(U8))
    s = fresh()
    msg = gcs.wire(BUILD[kind](gcs.tx, data))
    replies = s.handle(msg, 1.0, SRC) + s.tick(1.0)
    assert s.stats.received == 1 and s.stats.served + s.stats.errors == 1 and balanced(s)
    for reply, source in replies:          # every reply packs: no value outside its wire type
        reply.pack(gcs.robot_mav)
    if kind in ("COMMAND_LONG", "COMMAND_INT"):
        assert replies[0][0].get_type() == "COMMAND_ACK" and replies[0][0].command == msg.command
