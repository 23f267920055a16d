"""`mrta mission upload|download` against a small UDP vehicle: a MissionServer on a loopback socket in a
thread that answers whoever talks to it (and a GCS HEARTBEAT with its own)."""
from __future__ import annotations

import socket
import threading
import time
from pathlib import Path

import pytest

from runtime import cli
from runtime.comms import dialect
from runtime.comms.link import signing_timestamp
from runtime.comms.mission import MissionItem, MissionServer
from runtime.comms.mission_files import read_mission, read_wpl

MISSIONS = Path(__file__).resolve().parents[1] / "configs" / "missions"
WPL, PLAN = MISSIONS / "square_6.waypoints", MISSIONS / "square_6.plan"
KEY = bytes(range(32))
OLD = [MissionItem(0, 3, 16, x=33.7756, y=-84.3963)]


class UdpVehicle:
    """Robot stand-in: one UDP socket, a MissionServer, HEARTBEAT back to any ground station heard."""

    def __init__(self, sysid=3, key=None, verdict=None):
        self.mod = dialect.load()
        self.mav = self.mod.MAVLink(None, srcSystem=sysid, srcComponent=1)
        self.mav.robust_parsing = True
        if key:
            self.mav.signing.secret_key, self.mav.signing.sign_outgoing = key, True
            self.mav.signing.timestamp = signing_timestamp(time.time())
        self.items, self.plan, self.uploads = list(OLD), 1, 0
        self.server = MissionServer(self.mav, sysid, on_upload=self._upload, on_clear=lambda t: None,
                                    items=lambda t: self.items, plan_id=lambda t: self.plan,
                                    validate=lambda items: verdict)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.01)
        self.target = f"127.0.0.1:{self.sock.getsockname()[1]}"
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _upload(self, items):
        self.items, self.plan, self.uploads = list(items), self.plan + 1, self.uploads + 1
        return self.plan

    def _send(self, msg, addr):
        self.sock.sendto(msg.pack(self.mav), addr)
        self.mav.seq = (self.mav.seq + 1) % 256

    def _run(self):
        while not self._stop.is_set():
            try:
                data, addr = self.sock.recvfrom(65535)
            except socket.timeout:
                data = None
            now = time.monotonic()
            for m in (self.mav.parse_buffer(data) or []) if data else []:
                if m.get_type() == "HEARTBEAT" and m.type == self.mod.MAV_TYPE_GCS:
                    self._send(self.mav.heartbeat_encode(self.mod.MAV_TYPE_GROUND_ROVER,
                                                         self.mod.MAV_AUTOPILOT_GENERIC, 0, 0, 0), addr)
                for r in self.server.handle(m, now, addr):
                    self._send(r.msg, r.dest)
            for r in self.server.tick(now):
                self._send(r.msg, r.dest)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.sock.close()


def mrta(capsys, *argv) -> tuple[int, str, str]:
    rc = cli.main(["mission", *map(str, argv)])
    out, err = capsys.readouterr()
    return rc, out, err


def on_wire(items):
    mod = dialect.load()
    mav = mod.MAVLink(None, srcSystem=1, srcComponent=1)
    rx = mod.MAVLink(None)
    return [MissionItem.from_mavlink(rx.parse_buffer(it.to_mavlink_int(mav, 1, 1).pack(mav))[0])
            for it in items]


@pytest.mark.parametrize("path", [WPL, PLAN], ids=["wpl", "plan"])
def test_upload_then_download_gives_the_same_items(capsys, tmp_path, path):
    with UdpVehicle() as veh:
        rc, out, err = mrta(capsys, "upload", veh.target, path)
        assert (rc, err) == (0, "") and out.strip() == f"uploaded 6 items to system 3 at {veh.target}"
        assert veh.uploads == 1 and veh.items == on_wire(read_mission(path).items)
        rc, out, err = mrta(capsys, "download", "udp:" + veh.target, tmp_path / "back.waypoints")
        assert (rc, err) == (0, "") and out.strip() == f"wrote 6 items to {tmp_path / 'back.waypoints'}"
    assert read_wpl(tmp_path / "back.waypoints").items == veh.items == read_mission(path).items


def test_download_prints_a_table(capsys):
    with UdpVehicle(sysid=7) as veh:
        rc, out, err = mrta(capsys, "download", veh.target)
    assert rc == 0 and err == ""
    header, row = out.strip().splitlines()
    assert header.split() == ["seq", "frame", "command", "param1", "param2", "param3", "param4",
                              "x", "y", "z", "auto"]
    assert row.split() == ["0", "GLOBAL_RELATIVE_ALT", "NAV_WAYPOINT", "0", "0", "0", "0", "33.7756000",
                           "-84.3963000", "0", "1"]


def test_signed_upload(capsys, tmp_path):
    (tmp_path / "key").write_text(KEY.hex() + "\n")
    with UdpVehicle(key=KEY) as veh:
        rc, _, err = mrta(capsys, "upload", veh.target, WPL, "--key", tmp_path / "key")
        assert (rc, err) == (0, "") and veh.uploads == 1
        rc, _, err = mrta(capsys, "upload", veh.target, WPL, "--timeout", "0.5")      # unsigned: ignored
        assert rc == 1 and "no HEARTBEAT" in err and veh.uploads == 1


def test_bad_file_exits_2_with_one_line(capsys, tmp_path):
    bad = tmp_path / "mission.txt"
    lines = WPL.read_text().splitlines()
    lines[3] = "\t".join(lines[3].split("\t")[:9])
    bad.write_text("\n".join(lines) + "\n")
    with UdpVehicle() as veh:
        rc, out, err = mrta(capsys, "upload", veh.target, bad)
        assert veh.server.stats["received"] == 0
    assert (rc, out) == (2, "") and err == f"mrta: {bad}: line 4: expected 12 fields, got 9\n"


def test_bad_key_and_target_exit_2(capsys, tmp_path):
    (tmp_path / "key").write_text("abc")
    rc, _, err = mrta(capsys, "upload", "127.0.0.1:9", WPL, "--key", tmp_path / "key")
    assert rc == 2 and err.count("\n") == 1 and "expected 64 hex characters" in err
    rc, _, err = mrta(capsys, "download", "localhost", "--timeout", "0.2")
    assert rc == 2 and err == "mrta: TARGET: expected host:port, got 'localhost'\n"


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_no_vehicle_exits_1(capsys):
    target = f"127.0.0.1:{_free_udp_port()}"
    t0 = time.monotonic()
    rc, out, err = mrta(capsys, "upload", target, WPL, "--timeout", "0.5")
    assert (rc, out) == (1, "") and err.count("\n") == 1 and err.startswith(f"mrta: {target}: no HEARTBEAT")
    rc, out, err = mrta(capsys, "download", target, "--system", "3", "--timeout", "0.5")
    assert (rc, out) == (1, "") and err.count("\n") == 1 and "mission download unfinished" in err
    assert time.monotonic() - t0 < 3.0


def test_refused_upload_exits_1_and_the_vehicle_keeps_its_mission(capsys):
    with UdpVehicle(verdict=(6, "param1 must be >= 0")) as veh:
        rc, out, err = mrta(capsys, "upload", veh.target, PLAN)
        assert veh.items == OLD and veh.uploads == 0
    assert (rc, out) == (1, "")
    assert err == f"mrta: {veh.target}: system 3 refused the mission upload: MAV_MISSION_INVALID_PARAM1\n"
