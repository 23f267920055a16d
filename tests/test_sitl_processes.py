"""The fleet as `make run` runs it: one daemon process per robot, on the simulator's clock."""
from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest

from sitl import launcher
from tests.test_sitl_fleet import ROOT, _fleet_copy


@pytest.mark.slow
def test_cli_runs_fleet_of_daemon_processes(tmp_path):
    fleet = _fleet_copy(tmp_path)
    manifest = tmp_path / "manifest.json"
    proc = subprocess.run([sys.executable, "-m", "runtime.cli", "sitl", "run", str(fleet), "--speedup", "2",
                           "--manifest", str(manifest), "--run-dir", str(tmp_path / "run")],
                          capture_output=True, text=True, timeout=300, cwd=ROOT)
    print(proc.stdout[-1500:])
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "assignment valid: True" in proc.stdout
    assert "Hungarian optimum" in proc.stdout
    assert manifest.is_file()


@pytest.mark.slow
def test_dead_daemon_is_reported_and_peers_notice(tmp_path):
    """Three waypoints for four robots: robot 4 is killed 3 s in; the launcher reports it, the survivors' heartbeat
    timeout fires for it, the three tasks are done by them, and the verdict says robot 4 died."""
    tasks = [{"kind": "goto", "x": x, "y": y, "hold": 1.0} for x, y in ((-3.0, 0.0), (3.0, 0.0), (0.0, 3.5))]
    f = launcher.build(_fleet_copy(tmp_path, scenario={"type": "mission", "tasks": tasks}), tmp_path / "run")
    killed = {}

    def kill_robot_4(fleet):
        if fleet.world.t > 3.0 and not killed:
            killed["t"] = fleet.world.t
            os.kill(fleet.robots[4].proc.pid, signal.SIGKILL)
    try:
        res = launcher.run_processes(f, 2.0, timeout=60, on_step=kill_robot_4)
    finally:
        f.close()
    stats = launcher.daemon_stats(f)
    assert killed
    assert any("robot 4 daemon exited with code -9" in e for e in res["events"]), res["events"]
    assert res["lost"] == [4] and res["goal_met"], res["verdict"]
    assert all(4 not in r["by"] for r in res["tasks"]), res["tasks"]
    # the survivors' heartbeat timeout fired for robot 4
    for rid in (1, 2, 3):
        assert 4 in stats[rid]["peers_lost"], (rid, stats[rid])


@pytest.mark.slow
def test_the_verdict_says_why_a_formation_missing_a_robot_fails(tmp_path):
    """`mrta sitl run` with a daemon killed five seconds in: exit 1 and one line saying why (it exited 0 before)."""
    run_dir = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "runtime.cli", "sitl", "run", str(_fleet_copy(tmp_path)),
                             "--speedup", "2", "--timeout", "40", "--run-dir", str(run_dir)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    import time
    deadline = time.monotonic() + 90
    while not (run_dir / "clock").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(2.5)                                       # 5 s of sim time at 2x
    pid = next(int(p.name) for p in __import__("pathlib").Path("/proc").iterdir() if p.name.isdigit()
               and "robot_4.yaml" in _cmdline(p) and str(run_dir) in _cmdline(p))
    os.kill(pid, signal.SIGKILL)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 1, out[-2000:]
    assert err.strip().splitlines()[-1].startswith("mrta: goal not met: 4 positions to hold and 3 robots left")
    assert "robot(s) 4 died" in err and "verdict: goal not met" in out
    assert "    4  lost" in out


@pytest.mark.slow
def test_a_run_that_times_out_before_its_goal_exits_1_saying_so(tmp_path):
    """A formation that needs ~19 s given 3 s: exit 1, the verdict names the timeout (it printed a valid
    assignment and exited 0 before)."""
    proc = subprocess.run([sys.executable, "-m", "runtime.cli", "sitl", "run", str(_fleet_copy(tmp_path)),
                           "--speedup", "2", "--timeout", "3", "--run-dir", str(tmp_path / "run")], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1, proc.stdout[-2000:]
    assert proc.stderr.strip().splitlines()[-1].startswith("mrta: goal not met: timeout after 3 s"), proc.stderr
    assert "verdict: goal not met: timeout after 3 s" in proc.stdout and "lost" not in proc.stdout


@pytest.mark.slow
def test_daemons_end_when_the_launcher_is_killed(tmp_path):
    """SIGKILL the launcher: no daemon is left running (parent-death signal)."""
    import time
    fleet = _fleet_copy(tmp_path)
    run_dir = tmp_path / "run"
    sitl = subprocess.Popen([sys.executable, "-m", "runtime.cli", "sitl", "run", str(fleet), "--run-dir",
                             str(run_dir)], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while not (run_dir / "clock").exists():
        assert time.monotonic() < deadline and sitl.poll() is None
        time.sleep(0.05)
    # the launcher's own children: a child a daemon forks (a subprocess between fork and exec) shows the daemon's
    # command line for a moment too (a clean clone counted 5)
    pids = [int(p.name) for p in __import__("pathlib").Path("/proc").iterdir() if p.name.isdigit()
            and str(run_dir) in _cmdline(p) and " daemon " in _cmdline(p) and _ppid(p) == sitl.pid]
    assert len(pids) == 4, pids
    sitl.kill()
    sitl.wait()
    deadline = time.monotonic() + 10
    while any(_alive(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(_alive(pid) for pid in pids)


def _cmdline(proc_dir) -> str:
    try:
        return (proc_dir / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def _ppid(proc_dir) -> int | None:
    try:
        for line in (proc_dir / "status").read_text().splitlines():
            if line.startswith("PPid:"):
                return int(line.split()[1])
    except (OSError, ValueError):
        pass
    return None


def _alive(pid: int) -> bool:
    try:
        state = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"
