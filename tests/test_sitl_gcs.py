"""A stock pymavlink client on the ground-station port sees every robot as a ground rover that moves; a fleet run on
a passphrase key (`mrta sitl run FLEET --key FILE`) takes what MAVProxy signs after `signing key P`."""
from __future__ import annotations

import hashlib

import pytest
from pymavlink import mavutil

from runtime import config as C
from sitl import launcher
from tests.test_sitl_fleet import _fleet_copy


@pytest.mark.slow
def test_stock_pymavlink_client_sees_rovers_moving(tmp_path):
    fleet_path = _fleet_copy(tmp_path)
    f = launcher.build(fleet_path, tmp_path / "run")
    gcs_port = int(f.fleet.gcs.rsplit(":", 1)[1])
    client = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", source_system=255)
    seen_types: dict[int, set] = {}
    positions: dict[int, list] = {}

    def drain(_fleet):
        while True:
            m = client.recv_match(blocking=False)
            if m is None:
                return
            sysid = m.get_srcSystem()
            if m.get_type() == "HEARTBEAT":
                seen_types.setdefault(sysid, set()).add(m.type)
            elif m.get_type() == "GLOBAL_POSITION_INT":
                positions.setdefault(sysid, []).append((m.lat, m.lon))
    try:
        res = launcher.run_lockstep(f, timeout=60, on_step=drain, picture=False)
    finally:
        f.close()
        client.close()
    assert res["valid"]
    for rid in (1, 2, 3, 4):
        assert seen_types.get(rid) == {mavutil.mavlink.MAV_TYPE_GROUND_ROVER}, seen_types
        lat0, lon0 = positions[rid][0]
        lat1, lon1 = positions[rid][-1]
        # moved by more than a metre (1e-7 deg ~ 1.1 cm): positions that move
        assert abs(lat1 - lat0) + abs(lon1 - lon0) > 90, (rid, positions[rid][0], positions[rid][-1])
        assert len(positions[rid]) >= 4 * res["sim_time"] * 0.9     # >= 4 Hz


# ---------------------------------------------------------------------- a stock ground station's key

PASSPHRASE = "op4-fleet-pass"


@pytest.fixture
def passphrase_fleet(tmp_path):
    """operator_4 on free ports, lock-stepped, signed with the key `mrta key FILE --passphrase P` made (what
    `mrta sitl run FLEET --key FILE` builds), and a ground station with MAVProxy's key for P (`signing key P`)."""
    from runtime.cli import main
    from tests.sitl_util import StockGcs, shipped_fleet

    key_file = tmp_path / "fleet.key"
    assert main(["key", str(key_file), "--passphrase", PASSPHRASE]) == 0
    f = launcher.build(shipped_fleet(tmp_path, "operator_4.yaml"), tmp_path / "run", key=key_file)
    run = launcher.Lockstep(f)
    gcs = StockGcs(f.robots[1].udp_port, 1, hashlib.sha256(PASSPHRASE.encode()).digest())
    try:
        yield f, run, gcs, key_file
    finally:
        gcs.close()
        run.close()
        f.close()


def _autopilot_version(gcs):
    gcs.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
                              mavutil.mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0)


def test_a_fleet_run_on_a_passphrase_key_obeys_that_key_only(passphrase_fleet):
    """The fleet signs with the --key file, not a fresh key: a request signed with MAVProxy's key for the passphrase
    is answered, one signed with another key is dropped and counted; the key file outlives the run."""
    from tests.sitl_util import StockGcs

    f, run, gcs, key_file = passphrase_fleet
    assert f.key == hashlib.sha256(PASSPHRASE.encode()).digest() and f.fresh_key is None
    assert f.key_path == key_file.resolve()
    assert {C.load_robot(r.config_path).comms.signing_key for r in f.robots.values()} == {str(key_file.resolve())}
    link = run.daemons[1].link
    other = StockGcs(f.robots[1].udp_port, 1, hashlib.sha256(b"another-pass").digest())
    try:
        before = link.counters.bad_signature_dropped
        _autopilot_version(other)
        _autopilot_version(gcs)
        run.step()
        assert link.counters.bad_signature_dropped == before + 1
        seen = gcs.wait(lambda m: m.get_type() == "AUTOPILOT_VERSION", 5.0, run.step)
        assert seen and seen[-1].get_srcSystem() == 1
        assert not [m for m in other.drain() if m.get_type() == "AUTOPILOT_VERSION"]
    finally:
        other.close()
    f.close()
    assert key_file.exists()                     # a key of one's own is never removed with the run


def test_signing_setup_from_a_ground_station_leaves_the_fleet_key_and_says_why(passphrase_fleet):
    """MAVProxy's `signing setup P2` sends SETUP_SIGNING with a new key: the robot keeps its key, counts the refusal
    in its status snapshot, and tells the ground station why in one STATUSTEXT."""
    from runtime.comms.link import KEY_REFUSAL_TEXT

    f, run, gcs, _ = passphrase_fleet
    daemon = run.daemons[1]
    new = hashlib.sha256(b"another-pass").digest()
    gcs.mav.setup_signing_send(1, 1, list(new), gcs.mav.signing.timestamp)
    run.step()
    assert daemon.snapshot()["link"]["setup_signing_refused"] == 1
    seen = gcs.wait(lambda m: m.get_type() == "STATUSTEXT" and m.text == KEY_REFUSAL_TEXT, 5.0, run.step)
    assert seen and seen[-1].get_srcSystem() == 1
    assert daemon.link.mav.signing.secret_key == f.key
    _autopilot_version(gcs)                                     # the fleet key still commands the robot
    assert gcs.wait(lambda m: m.get_type() == "AUTOPILOT_VERSION", 5.0, run.step)


def test_every_ftp_request_is_answered_within_one_control_cycle(passphrase_fleet):
    """MAVProxy's parameter download opens @PARAM/param.pck over MAVLink FTP (OpenFileRO, opcode 4) and waits ~3 s
    for an answer before it falls back to PARAM_REQUEST_LIST: every FTP request gets its ACK or NAK (seq + 1, the
    request's opcode echoed, data[0] the MAV_FTP_ERR code) from the very next control cycle of the robot."""
    import struct

    f, run, gcs, _ = passphrase_fleet
    asked = {4: (b"@PARAM/param.pck?withdefaults=1", 129, 10), 3: (b"/", 129, 10), 5: (b"", 129, 4),
             6: (b"x", 129, 9), 77: (b"", 129, 7), 0: (b"", 128, None)}
    for k, (opcode, (name, _, _)) in enumerate(asked.items()):
        raw = struct.pack("<HBBBBBBI", 100 * k + 7, 0, opcode, len(name), 0, 0, 0, 0) + name
        gcs.mav.file_transfer_protocol_send(0, 1, 1, list(raw.ljust(251, b"\0")))
    run.step()                                                 # one control cycle, no more
    replies = {}
    for _ in asked:
        seen = gcs.wait(lambda m: m.get_type() == "FILE_TRANSFER_PROTOCOL", 5.0)
        assert seen and seen[-1].get_type() == "FILE_TRANSFER_PROTOCOL", f"answered {sorted(replies)} of {sorted(asked)}"
        m = seen[-1]
        assert (m.target_system, m.target_component) == (255, 190)
        seq, session, op, size, req_op = struct.unpack("<HBBBB", bytes(m.payload[:6]))
        replies[req_op] = (seq, op, size, m.payload[12] if size else None)
    assert replies == {opcode: (100 * k + 8, reply, 1 if err is not None else 0, err)
                       for k, (opcode, (_, reply, err)) in enumerate(asked.items())}
