"""Issue 32 point 1: the robot config's ``sensors:`` list, the daemon opening it, the launcher serving its twins.

A bad entry is one line and exit 2; an older ``gps:`` section still loads as one ``nmea_gps`` entry; the core merges
a scanner's ranges after the base's; the launcher writes each entry's endpoint into the robot config and the
manifest, and a stock PyPI client (pyrplidar) reads scans from the pty the manifest names."""
from __future__ import annotations

import json
import math
import threading
import time
from pathlib import Path

import pytest
import yaml

from runtime import config as C
from runtime.drivers.base import BaseSensors
from runtime.robot.core import sensors_with

ROOT = Path(__file__).resolve().parents[1]


def _run(tmp_path, data, capsys) -> tuple[int, str]:
    """``mrta daemon FILE --check`` in this process: its exit code and what it printed on stderr."""
    from runtime.cli import main
    p = tmp_path / "robot.yaml"
    p.write_text(yaml.safe_dump(data))
    code = main(["daemon", str(p), "--check"])
    return code, capsys.readouterr().err


@pytest.mark.parametrize("entry, says", [
    ({"type": "lidarx", "port": "loop://"}, "sensors[0].type: expected one of nmea_gps|rplidar, got 'lidarx'"),
    ({"type": "rplidar", "port": "/dev/no-such-tty"}, "sensors[0].port: expected a serial device that exists"),
    ({"type": "rplidar", "port": "loop://", "mount": [0, 0, 9]}, "sensors[0].mount[2]: expected a number in"),
    ({"type": "rplidar", "port": "loop://", "mount": [0, 0]}, "sensors[0].mount: expected a list of 3 numbers"),
])
def test_a_bad_sensor_entry_is_one_line_and_exit_2(tmp_path, capsys, entry, says):
    code, err = _run(tmp_path, {"robot": {"id": 3}, "base": {"port": "loop://"}, "sensors": [entry]}, capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and says in err, err


def test_an_older_gps_section_loads_as_one_nmea_gps_entry_and_both_at_once_is_one_line(tmp_path):
    old = C.from_dict(C.RobotConfig, {"gps": {"port": "/dev/ttyS7", "baudrate": 4800}})
    (gps,) = old.sensor_list()
    assert (gps.type, gps.port, gps.baudrate) == ("nmea_gps", "/dev/ttyS7", 4800) and old.has_gps
    assert C.from_dict(C.RobotConfig, {"gps": {"enabled": False}}).sensor_list() == ()
    new = C.from_dict(C.RobotConfig, {"sensors": [{"type": "nmea_gps", "port": "/dev/ttyS8"}]})
    assert [s.port for s in new.sensor_list()] == ["/dev/ttyS8"]
    p = tmp_path / "both.yaml"
    p.write_text(yaml.safe_dump({"gps": {"port": "loop://"}, "sensors": [{"type": "nmea_gps"}]}))
    with pytest.raises(C.ConfigError, match=r"both.yaml: gps: expected no gps: section beside sensors\[0\]"):
        C.load_robot(p)


def test_the_core_puts_a_scanners_ranges_after_the_bases():
    base = BaseSensors(bump_left=True, ranges=((0.0, 1.0),))
    assert sensors_with(base, ()) is base
    merged = sensors_with(base, [(math.pi, 2.0)])
    assert merged.ranges == ((0.0, 1.0), (math.pi, 2.0)) and merged.bump_left and base.ranges == ((0.0, 1.0),)
    assert sensors_with(None, ()).ranges == ()


def test_the_daemon_opens_its_entries_and_tells_the_agent_the_kinds(tmp_path):
    from runtime.daemon import Daemon
    cfg = C.from_dict(C.RobotConfig, {
        "robot": {"id": 2}, "base": {"type": "arcos", "port": "loop://"}, "comms": {"listen": "127.0.0.1:0"},
        "sensors": [{"type": "rplidar", "port": "loop://"}, {"type": "nmea_gps", "port": "loop://"}],
        "allocation": {"method": "comutar"}})
    d = Daemon(cfg)
    try:
        assert [p.kind for p in d.sensor_parts] == ["laser", "gps"] and d.gps is d.sensor_parts[1]
        assert d.core.base.kinds == ("gps", "laser", "sonar") and d.core.base.ranging
        assert d.core.agent.catalogue.sensors == ("laser", "sonar")
    finally:
        d.close()


def test_a_stock_client_reads_scans_from_the_pty_a_devices_only_manifest_names(tmp_path):
    pytest.importorskip("pybullet")
    pyrplidar = pytest.importorskip("pyrplidar")
    from sitl import launcher
    from tests.sitl_util import shipped_fleet

    f = launcher.build(shipped_fleet(tmp_path, "comutar_3_laser.yaml"), tmp_path / "run")
    stop, lock = threading.Event(), threading.Lock()

    def serve():                                   # --devices-only: the world and its devices on wall time
        t0 = time.monotonic()
        while not stop.is_set():
            with lock:
                f.advance_to(time.monotonic() - t0)
            time.sleep(0.002)
    th = threading.Thread(target=serve, daemon=True)
    try:
        robots = {r["id"]: r for r in json.loads(f.manifest_path.read_text())["robots"]}
        assert robots[1]["sensors"] == [] and robots[3]["sensors"] == []
        (entry,) = robots[2]["sensors"]
        assert entry["type"] == "rplidar" and Path(entry["port"]).exists()
        written = C.load_robot(robots[2]["config"])
        assert [(s.type, s.port) for s in written.sensors] == [("rplidar", entry["port"]),
                                                                 ("nmea_gps", robots[2]["gps"]["device"])]
        th.start()
        lidar = pyrplidar.PyRPlidar()
        lidar.connect(port=entry["port"], baudrate=115200, timeout=3)
        try:
            assert lidar.get_info().model == 0x18 and lidar.get_health().status == 0
            got = []
            for m in lidar.start_scan()():
                if m.start_flag and got:
                    break
                if got or m.start_flag:
                    got.append((m.angle, m.distance))
                if len(got) > 2000:
                    break
            lidar.stop()
        finally:
            lidar.disconnect()
        # robot 2 at (-3.5, 0) facing +x in a 10 m arena: the wall behind it (180 degrees) 1.5 m away
        behind = [mm for a, mm in got if abs(a - 180.0) < 1.0 and mm > 0]
        assert len(got) >= 300 and behind and all(abs(mm / 1000.0 - 1.5) < 0.03 for mm in behind), behind
    finally:
        stop.set()
        if th.is_alive():
            th.join(5)
        f.close()
