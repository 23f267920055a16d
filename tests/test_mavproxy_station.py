"""The real MAVProxy (``mavproxy.py`` from this Python's environment; make test installs it without its map and
camera requirements) against
operator_4 signed with the key of a passphrase (`mrta key FILE --passphrase P`, `mrta sitl run FLEET --key FILE`):
with `signing key P` it loads the parameters (no FTP timeout), uploads a waypoint file whose home line the robot
skips, sees every waypoint reached, reads the mission back and disarms and arms robot 1; without the passphrase it
sees the robot and nothing it says is taken.  Without a key at all it commands a fleet run with --no-signing, and a
signed one that lists its network in comms.unsigned_gcs (--unsigned-gcs 127.0.0.1/32).

MAVProxy runs as a subprocess reading commands on stdin (as typed at its prompt), connected to robot 1's MAVLink
port (``--master=udpout:``, as docs/ground-station.md says); the fleet is lock-stepped in this process and paced
to at most ``SPEEDUP`` x wall time, so MAVProxy's wall-clock retries meet a robot that answers within a few control
cycles.  Every wait is bounded."""
from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("MAVProxy", reason="MAVProxy is not installed: make test installs it (pip install --no-deps 'MAVProxy>=1.8.75', see the Makefile)")

MAVPROXY = Path(sys.executable).parent / "mavproxy.py"
PASSPHRASE = "op4-mavproxy"
SPEEDUP = 4.0                 # sim seconds per wall second, at most
# three waypoints (fleet frame, m), each a short drive from a robot's start in operator_4 (+-2, +-2)
WAYPOINTS = [(-1.4, -1.4), (1.4, 1.4), (-1.4, 1.4)]


def _waypoint_file(path: Path, datum) -> Path:
    """A QGC WPL 110 file as MAVProxy writes one: the home line (the datum), then the waypoints (relative alt)."""
    import pymap3d

    lines = ["QGC WPL 110", f"0\t1\t0\t16\t0\t0\t0\t0\t{datum.lat:.7f}\t{datum.lon:.7f}\t{datum.alt:.1f}\t1"]
    for k, (x, y) in enumerate(WAYPOINTS, 1):
        lat, lon, _ = pymap3d.enu2geodetic(x, y, 0.0, datum.lat, datum.lon, datum.alt)
        lines.append(f"{k}\t0\t3\t16\t0\t0\t0\t0\t{lat:.7f}\t{lon:.7f}\t0.0\t1")
    path.write_text("\n".join(lines) + "\n")
    return path


class MavProxy:
    """mavproxy.py on robot ``port``: ``type(line)`` as at its prompt; ``until(text)`` steps the fleet (``pace``)
    until a line of its output since the last ``mark()`` holds ``text``, or ``timeout`` wall seconds pass."""

    def __init__(self, port: int, workdir: Path, pace):
        workdir.mkdir(parents=True, exist_ok=True)
        env = dict(os.environ, HOME=str(workdir), PYTHONUNBUFFERED="1")    # no ~/.mavinit.scr, output at once
        env.pop("DISPLAY", None)
        self.proc = subprocess.Popen(
            [str(MAVPROXY), f"--master=udpout:127.0.0.1:{port}", "--source-system", "255", "--mav20",
             "--state-basedir", str(workdir)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1,
            env=env, cwd=workdir)
        self.lines: list[str] = []
        self._from = 0
        self.pace = pace
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def type(self, line: str) -> None:
        self.lines.append(f">>> {line}")
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()

    def mark(self) -> None:
        self._from = len(self.lines)

    def since(self) -> list[str]:
        return self.lines[self._from:]

    def until(self, text: str, timeout: float = 10.0, whole: bool = False) -> bool:
        """``whole``: the line, its prompt (``HOLD> ``) left out, is ``text`` (``ARMED`` is not ``DISARMED``)."""
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            if any((line.rpartition("> ")[2].strip() == text) if whole else text in line
                   for line in self.lines[self._from:]):
                return True
            if self.proc.poll() is not None:
                return False
            self.pace()
        return False

    def run_for(self, seconds: float) -> None:
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            self.pace()

    def output(self) -> str:
        return "\n".join(self.lines)

    def close(self) -> None:
        try:
            self.proc.stdin.close()             # EOF at its prompt: MAVProxy stops
        except OSError:
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(timeout=10)
        self._reader.join(timeout=5)


@pytest.fixture
def fleet(request, tmp_path):
    """operator_4 on free ports, lock-stepped, signed with the key of PASSPHRASE (the fixture's param, if given:
    "no-signing", an unsigned fleet; "unsigned-gcs", signed and taking unsigned frames from 127.0.0.1/32);
    ``pace()`` steps it to at most SPEEDUP x the wall time since the fixture started."""
    from runtime.cli import main
    from sitl import launcher
    from tests.sitl_util import shipped_fleet

    if not MAVPROXY.exists():
        pytest.skip(f"no {MAVPROXY} (make test installs it: pip install --no-deps 'MAVProxy>=1.8.75')")
    how = getattr(request, "param", "passphrase")
    key_file = tmp_path / "fleet.key"
    assert main(["key", str(key_file), "--passphrase", PASSPHRASE]) == 0
    f = launcher.build(shipped_fleet(tmp_path, "operator_4.yaml"), tmp_path / "run",
                       key=None if how == "no-signing" else key_file, signing=how != "no-signing",
                       unsigned_gcs=["127.0.0.1/32"] if how == "unsigned-gcs" else None)
    assert (f.key is None) == (how == "no-signing")
    run = launcher.Lockstep(f)
    wall0, sim0 = time.monotonic(), f.world.t

    def pace() -> None:
        if f.world.t < sim0 + (time.monotonic() - wall0) * SPEEDUP:
            run.step()
        else:
            time.sleep(0.002)

    try:
        yield f, run, pace
    finally:
        run.close()
        f.close()


def _tasks(run, rid=1) -> list:
    return run.daemons[rid].core.node.table.listing()


def _disarm_and_arm(mp: MavProxy, node) -> None:
    """`disarm`, then `arm throttle`: each acknowledged, shown in the HEARTBEAT (MAVProxy's DISARMED / ARMED) and
    in force on the robot."""
    for command, said, armed in (("disarm", "DISARMED", False), ("arm throttle", "ARMED", True)):
        mp.mark()
        mp.type(command)
        assert mp.until("COMPONENT_ARM_DISARM: ACCEPTED") and mp.until(said, whole=True), mp.output()
        assert node.armed == armed


def test_mavproxy_with_the_passphrase_commands_the_signed_fleet(fleet, tmp_path):
    from runtime.messages import DONE

    f, run, pace = fleet
    mp = MavProxy(f.robots[1].udp_port, tmp_path / "mavproxy", pace)
    try:
        assert mp.until("online system 1", 30.0), mp.output()
        mp.mark()
        mp.type(f"signing key {PASSPHRASE}")
        assert mp.until("Setup signing key"), mp.output()
        # MAVProxy's parameter module asks for the parameters on connect (an FTP open of @PARAM/param.pck, NAKed,
        # then PARAM_REQUEST_LIST); ask once more now that it signs
        mp.type("param fetch")
        assert mp.until("Received 10 parameters", 15.0), mp.output()
        mp.type("param show CTL_CRUISE_SPD")
        assert mp.until("CTL_CRUISE_SPD"), mp.output()

        mp.mark()
        wpfile = _waypoint_file(tmp_path / "three.waypoints", f.world_cfg.datum)
        mp.type(f"wp load {wpfile}")
        assert mp.until("MISSION_ACK: TYPE_MISSION: ACCEPTED"), mp.output()
        assert mp.until(f"mission: {len(WAYPOINTS)} task(s) added, 0 already known, home item 0 skipped"), \
            mp.output()
        assert len(_tasks(run)) == len(WAYPOINTS)          # the home line is no task

        # every waypoint reached: each task done, reported reached by the robot that drove to it
        t0 = time.monotonic()
        while time.monotonic() - t0 < 30.0 and not all(e.state == DONE for e in _tasks(run)):
            pace()
        assert [e.state for e in _tasks(run)] == [DONE] * len(WAYPOINTS), mp.output()
        reached = set().union(*(set(d.core.ground.reached) for d in run.daemons.values()))
        assert reached == set(range(len(WAYPOINTS)))

        mp.mark()
        mp.type("wp list")
        assert mp.until(f"Saved {len(WAYPOINTS)} waypoints"), mp.output()
        listed = [line for line in mp.since() if "16 3 " in line]            # command 16, frame 3, lat, lon
        assert len(listed) == len(WAYPOINTS), mp.output()
        saved = (tmp_path / "mavproxy" / "way.txt").read_text().splitlines()
        wanted = wpfile.read_text().splitlines()
        latlon = lambda lines: [tuple(float(v) for v in line.split()[8:10]) for line in lines]      # noqa: E731
        assert latlon(saved[1:]) == [pytest.approx(p, abs=1e-6) for p in latlon(wanted[2:])]    # MAVProxy: %f

        _disarm_and_arm(mp, run.daemons[1].core.node)
    finally:
        mp.close()
    out = mp.output()
    assert "Requested parameter list (ftp)" in out and "FTP: request timed out" not in out, out
    link = run.daemons[1].snapshot()["link"]
    assert link["bad_signature_dropped"] == 0 and link["unsigned_gcs_taken"] == 0


def test_mavproxy_without_the_passphrase_sees_the_robot_and_is_not_obeyed(fleet, tmp_path):
    f, run, pace = fleet
    mp = MavProxy(f.robots[1].udp_port, tmp_path / "mavproxy", pace)
    node = run.daemons[1].core.node
    try:
        assert mp.until("online system 1", 30.0), mp.output()        # its heartbeats and telemetry arrive
        mp.mark()
        mp.type("param fetch")
        mp.type(f"wp load {_waypoint_file(tmp_path / 'three.waypoints', f.world_cfg.datum)}")
        mp.type("disarm")
        mp.run_for(5.0)
        said = mp.since()
    finally:
        mp.close()
    out = mp.output()
    assert not [line for line in said if "Received" in line and "parameters" in line], out
    assert not [line for line in said if "MISSION_ACK" in line or "COMMAND_ACK" in line], out
    assert _tasks(run) == [] and node.armed
    link = run.daemons[1].snapshot()["link"]
    assert link["unsigned_dropped"] > 0 and link["unsigned_gcs_taken"] == 0, link


@pytest.mark.parametrize("fleet", ["no-signing", "unsigned-gcs"], indirect=True)
def test_mavproxy_without_a_key_commands_an_unsigned_fleet_and_one_that_lists_its_network(fleet, tmp_path):
    """A fleet started with --no-signing, and a signed one with --unsigned-gcs 127.0.0.1/32: MAVProxy, which never
    typed `signing key`, loads the parameters, uploads a mission and disarms and arms robot 1."""
    f, run, pace = fleet
    mp = MavProxy(f.robots[1].udp_port, tmp_path / "mavproxy", pace)
    node = run.daemons[1].core.node
    try:
        assert mp.until("online system 1", 30.0), mp.output()
        mp.mark()
        mp.type("param fetch")
        assert mp.until("Received 10 parameters", 15.0), mp.output()
        mp.type(f"wp load {_waypoint_file(tmp_path / 'three.waypoints', f.world_cfg.datum)}")
        assert mp.until("MISSION_ACK: TYPE_MISSION: ACCEPTED"), mp.output()
        assert len(_tasks(run)) == len(WAYPOINTS)
        _disarm_and_arm(mp, node)
    finally:
        mp.close()
    link = run.daemons[1].snapshot()["link"]
    if f.key is not None:                 # signed: what MAVProxy sent was taken unsigned, and counted so
        assert link["unsigned_gcs_taken"] > 0, link
