"""`mrta mission upload|download` against a small UDP vehicle: a MissionServer on a loopback socket in a
thread that answers whoever talks to it (and a GCS HEARTBEAT with its own)."""
from __future__ import annotations

import os
import socket
import threading
import time
from pathlib import Path

import pytest
from hypothesis import HealthCheck, example, given, settings, strategies as st

from runtime import cli
from runtime.comms import dialect
from runtime.comms.link import signing_timestamp
from runtime.comms.mission import MissionItem, MissionServer, added_report
from runtime.comms.mission_files import read_mission, read_wpl

MISSIONS = Path(__file__).resolve().parents[1] / "configs" / "missions"
WPL, PLAN = MISSIONS / "square_6.waypoints", MISSIONS / "square_6.plan"
KEY = bytes(range(32))
OLD = [MissionItem(0, 3, 16, x=33.7756, y=-84.3963)]


class UdpVehicle:
    """Robot stand-in: one UDP socket, a MissionServer, HEARTBEAT back to any ground station heard."""

    def __init__(self, sysid=3, key=None, verdict=None, report=True):
        self.mod = dialect.load()
        self.mav = self.mod.MAVLink(None, srcSystem=sysid, srcComponent=1)
        self.mav.robust_parsing = True
        if key:
            self.mav.signing.secret_key, self.mav.signing.sign_outgoing = key, True
            self.mav.signing.timestamp = signing_timestamp(time.time())
        self.items, self.plan, self.uploads, self.clears = list(OLD), 1, 0, 0
        self.report, self.texts = report, []       # the robot's STATUSTEXT of an upload, sent before its ACK
        self.server = MissionServer(self.mav, sysid, on_upload=self._upload, on_clear=self._clear,
                                    items=lambda t: self.items, plan_id=lambda t: self.plan,
                                    validate=lambda items: verdict)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.01)
        self.target = f"127.0.0.1:{self.sock.getsockname()[1]}"
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _upload(self, items):
        known = sum(it in self.items for it in items)       # as a robot: the same item at the same seq is known
        if self.report:
            self.texts.append(added_report(len(items) - known, known))
        self.items, self.plan, self.uploads = list(items), self.plan + 1, self.uploads + 1
        return self.plan

    def _clear(self, mission_type):
        self.clears += 1

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
                replies = self.server.handle(m, now, addr)
                for text in self.texts:
                    self._send(self.mav.statustext_encode(6, text.encode()), addr)
                self.texts.clear()
                for r in replies:
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
        assert (rc, err) == (0, "")
        assert out.strip() == f"uploaded 6 items to system 3 at {veh.target}: 6 new tasks, 0 already known"
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
    assert time.monotonic() - t0 < 30.0      # a hang guard (30 times the two timeouts), not a timing assert


def test_refused_upload_exits_1_and_the_vehicle_keeps_its_mission(capsys):
    with UdpVehicle(verdict=(6, "param1 must be >= 0")) as veh:
        rc, out, err = mrta(capsys, "upload", veh.target, PLAN)
        assert veh.items == OLD and veh.uploads == 0
    assert (rc, out) == (1, "")
    assert err == f"mrta: {veh.target}: system 3 refused the mission upload: MAV_MISSION_INVALID_PARAM1\n"


def test_a_second_upload_of_the_same_items_says_no_task_was_new(capsys):
    with UdpVehicle() as veh:
        assert mrta(capsys, "upload", veh.target, WPL)[0] == 0
        rc, out, err = mrta(capsys, "upload", veh.target, WPL)
    assert (rc, err) == (0, "") and veh.uploads == 2
    assert out.strip() == f"uploaded 6 items to system 3 at {veh.target}: 0 new tasks, 6 already known"


def test_without_the_robots_report_the_upload_says_it_does_not_know(capsys):
    with UdpVehicle(report=False) as veh:
        t0 = time.monotonic()
        rc, out, err = mrta(capsys, "upload", veh.target, WPL)
    assert (rc, err) == (0, "") and time.monotonic() - t0 < 30.0    # a hang guard, not a timing assert
    assert out.strip() == (f"uploaded 6 items to system 3 at {veh.target}: accepted; the robot did not report "
                           "how many were new tasks")


def _cut(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize("name, text", [
    ("header.waypoints", "QGC WPL 110\n"),                                 # cut to its header
    ("home.waypoints", "QGC WPL 110\n" + WPL.read_text().splitlines()[1] + "\n"),   # cut after the home line
    ("empty.plan", '{"fileType": "Plan", "mission": {"items": []}}'),
])
def test_a_mission_file_without_items_is_refused_unless_clear(capsys, tmp_path, name, text):
    path = _cut(tmp_path, name, text)
    with UdpVehicle() as veh:
        rc, out, err = mrta(capsys, "upload", veh.target, path)
        assert (rc, out) == (2, "") and veh.server.stats["received"] == 0 and veh.items == OLD
        assert err == (f"mrta: {path}: expected at least one mission item, got none (an empty or cut mission file; "
                       "uploading no items withdraws the fleet's open tasks: pass --clear to do that)\n")
        rc, out, err = mrta(capsys, "upload", veh.target, path, "--clear")
        assert (rc, err) == (0, "") and veh.clears == 1 and veh.uploads == 0
        assert out.strip() == (f"cleared: system 3 at {veh.target} accepted MISSION_CLEAR_ALL (the fleet withdraws "
                               "its open tasks)")


def test_clear_needs_no_file_and_refuses_one_with_items(capsys):
    with UdpVehicle() as veh:
        rc, out, err = mrta(capsys, "upload", veh.target, "--clear")
        assert (rc, err) == (0, "") and veh.clears == 1
        rc, out, err = mrta(capsys, "upload", veh.target, WPL, "--clear")
        assert (rc, out) == (2, "") and veh.clears == 1 and veh.uploads == 0
        assert err == (f"mrta: {WPL}: --clear withdraws the fleet's open tasks and uploads nothing: expected a file "
                       "with no items (or no FILE), got 6\n")
        rc, out, err = mrta(capsys, "upload", veh.target)
        assert rc == 2 and err == ("mrta: upload: expected FILE, a mission file (or --clear to withdraw the fleet's "
                                   "open tasks)\n")
        assert veh.server.stats["handled"] == 1                       # the one MISSION_CLEAR_ALL


@pytest.mark.parametrize("cut", ["mid_line", "lost_line"])
def test_a_cut_or_damaged_file_is_refused_before_the_robot_is_asked(capsys, tmp_path, cut):
    text = WPL.read_text()
    lines = text.splitlines(keepends=True)
    if cut == "mid_line":
        text, expected = text[:text.index(lines[4]) + 20], "line 5: expected 12 fields, got 7"
    else:
        text, expected = "".join(lines[:3] + lines[4:]), "line 4: INDEX: expected 2 (a line lost or repeated?), got 3"
    path = _cut(tmp_path, "cut.waypoints", text)
    with UdpVehicle() as veh:
        rc, out, err = mrta(capsys, "upload", veh.target, path)
        assert veh.server.stats["received"] == 0
    assert (rc, out, err) == (2, "", f"mrta: {path}: {expected}\n")


@pytest.mark.parametrize("value", ["0", "0.05", "3601", "nan", "inf", "1e308"])
def test_timeout_is_bounded(capsys, value):
    for action in (["upload", "robot", str(WPL)], ["download", "robot"], ["status", "robot"]):  # fails fast if unchecked
        rc, out, err = mrta(capsys, *action, "--timeout", value)
        assert (rc, out) == (2, "")
        assert err == f"mrta: --timeout: expected a number in [0.1, 3600], got {float(value)!r}\n"


def test_download_checks_its_output_path_before_asking_the_robot(capsys, tmp_path):
    (tmp_path / "ro").mkdir()
    (tmp_path / "ro").chmod(0o500)
    cases = [(tmp_path, "expected a file name, got a folder"),
             (tmp_path / "nope" / "m.waypoints", "expected a file in an existing folder"),
             (tmp_path / "ro" / "m.waypoints", "expected a place this user can write")]
    try:
        with UdpVehicle() as veh:
            for path, says in cases:
                if says.startswith("expected a place") and os.access(tmp_path / "ro", os.W_OK):
                    continue                                          # root writes anywhere
                rc, out, err = mrta(capsys, "download", veh.target, path)
                assert (rc, out) == (2, "") and err.count("\n") == 1 and f"FILE {path}: {says}" in err, err
            assert veh.server.stats["received"] == 0
    finally:
        (tmp_path / "ro").chmod(0o700)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(src=st.sampled_from([WPL, PLAN]), flips=st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 7)), max_size=4),
       cut=st.integers(0, 10**6) | st.tuples(st.just("line end"), st.integers(0, 100)),
       timeout=st.floats(allow_nan=True, allow_infinity=True) | st.sampled_from([0.1, 10.0, 3600.0]), clear=st.booleans())
@example(src=WPL, flips=[], cut=("line end", 0), timeout=10.0, clear=False)          # cut to its header
@example(src=WPL, flips=[], cut=("line end", 1), timeout=10.0, clear=False)          # cut after its home line
def test_random_damaged_files_and_options_exit_2_with_one_line(capsys, tmp_path, src, flips, cut, timeout, clear):
    """Bit-flipped or cut copies of the example files, random --timeout values and --clear: the upload never
    raises, and with a TARGET that is no address it always ends with exit 2 and one line (the file, the option or
    TARGET), before any socket is opened; only a file and options that pass every check get as far as TARGET."""
    raw = bytearray(src.read_bytes())
    for i, bit in flips:
        raw[i % len(raw)] ^= 1 << bit
    line_ends = [i + 1 for i, b in enumerate(raw) if b == ord("\n")]
    if isinstance(cut, tuple):
        end = line_ends[cut[1] % len(line_ends)] if line_ends else 0
    else:
        end = cut % (len(raw) + 1)
    path = tmp_path / f"m{src.suffix}"
    path.write_bytes(bytes(raw[:end]))
    argv = ["upload", "robot", path, f"--timeout={timeout!r}"] + (["--clear"] if clear else [])
    rc, out, err = mrta(capsys, *argv)
    assert (rc, out) == (2, "") and err.startswith("mrta: ") and err.count("\n") == 1, err
    if err.startswith("mrta: TARGET"):
        assert bool(read_mission(path).items) != clear and 0.1 <= timeout <= 3600


class RobotOnUdp(UdpVehicle):
    """A real robot core (its ground services: the mission server, the fleet's task table and the robot's own
    report of an upload) behind the same loopback socket, stepped in sim time as datagrams come."""

    def __init__(self):
        from runtime import config as C
        from runtime.comms.link import LinkCounters
        from runtime.robot.core import RobotCore
        from runtime.robot.ports import BaseFacts
        super().__init__(sysid=1)
        cfg = C.from_dict(C.RobotConfig, {"robot": {"id": 1}, "gps": {"enabled": False},
                                          "planning": {"planner": "euclid"}}, "robot.yaml")
        self.core = RobotCore(cfg, BaseFacts(radius=0.17), mavlink=(self.mav, self.mod, LinkCounters()))
        self.stations: set = set()

    def _run(self):
        from runtime.drivers.base import BaseSensors
        from runtime.robot.core import GCS, TO, Inbox, Sensed
        now = 0.0
        while not self._stop.is_set():
            try:
                data, addr = self.sock.recvfrom(65535)
            except socket.timeout:
                data = None
            inbox = []
            for m in (self.mav.parse_buffer(data) or []) if data else []:
                self.stations.add(addr)
                if m.get_type() == "HEARTBEAT":
                    self._send(self.mav.heartbeat_encode(self.mod.MAV_TYPE_GROUND_ROVER,
                                                         self.mod.MAV_AUTOPILOT_GENERIC, 0, 0, 0), addr)
                else:
                    inbox.append((m, addr))
            now += 0.05
            out = self.core.step(now, Sensed(pose=(0.0, 0.0, 0.0), sensors=BaseSensors()),
                                 Inbox(ground=inbox, ground_present=bool(self.stations)))
            for frame in out.frames:
                if hasattr(frame[1], "pack"):                   # pymavlink messages; our dataclasses are left out
                    for to in [frame[2]] if frame[0] == TO else sorted(self.stations) if frame[0] == GCS else []:
                        self._send(frame[1], to)


def test_upload_to_a_robot_core_reports_the_tasks_it_added(capsys):
    with RobotOnUdp() as robot:
        rc, out, err = mrta(capsys, "upload", robot.target, WPL)
        assert (rc, err) == (0, "") and len(robot.core.port.listing()) == 6
        assert out.strip() == f"uploaded 6 items to system 1 at {robot.target}: 6 new tasks, 0 already known"
        rc, out, err = mrta(capsys, "upload", robot.target, WPL)
        assert (rc, err) == (0, "") and len(robot.core.port.listing()) == 6
        assert out.strip() == f"uploaded 6 items to system 1 at {robot.target}: 0 new tasks, 6 already known"
