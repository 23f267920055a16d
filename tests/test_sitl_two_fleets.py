"""Two fleets on one machine (issue 14, item 3): a second `mrta sitl run` of the same fleet is refused with exit 2
naming the busy port while the first runs; with `--instance 1` it runs beside the first and both end with a true
verdict.  The fast test checks the refusal alone, against a port held by this test."""
from __future__ import annotations

import socket
import subprocess
import sys
import time

import pytest

from runtime import cli
from tests.sitl_util import ROOT, shipped_fleet


def _mrta(*args: str) -> list[str]:
    return [sys.executable, "-m", "runtime.cli", *args]


def _bound(port: int) -> bool:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.bind(("127.0.0.1", port))
        return False
    except OSError:
        return True
    finally:
        s.close()


def test_a_busy_robot_port_is_refused_with_one_line_naming_it(tmp_path, capsys):
    import yaml
    fleet = shipped_fleet(tmp_path, "create2_4.yaml")
    port = yaml.safe_load(fleet.read_text())["base_port"] + 3
    held = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    held.bind(("127.0.0.1", port))
    try:
        assert cli.main(["sitl", "run", str(fleet), "--run-dir", str(tmp_path / "run")]) == 2
    finally:
        held.close()
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("mrta: "), err
    assert f"127.0.0.1:{port} (robot 3's MAVLink port) is in use" in err and "--instance N" in err
    assert not (tmp_path / "run").exists()          # refused before anything was built


@pytest.mark.slow
def test_a_second_fleet_is_refused_then_runs_beside_the_first_with_instance_1(tmp_path):
    import yaml
    fleet = shipped_fleet(tmp_path, "create2_4.yaml")
    base = yaml.safe_load(fleet.read_text())["base_port"]
    first = subprocess.Popen(_mrta("sitl", "run", str(fleet), "--speedup", "2", "--run-dir", str(tmp_path / "a")),
                             cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    second = None
    try:
        deadline = time.monotonic() + 60
        while not all(_bound(base + rid) for rid in (1, 2, 3, 4)):        # the first fleet's daemons are up
            assert first.poll() is None and time.monotonic() < deadline, "the first fleet did not start"
            time.sleep(0.1)
        same = subprocess.run(_mrta("sitl", "run", str(fleet), "--run-dir", str(tmp_path / "b")), cwd=ROOT,
                              capture_output=True, text=True, timeout=60)
        assert same.returncode == 2, same.stderr
        assert same.stderr.count("\n") == 1 and f"127.0.0.1:{base + 1} (robot 1's MAVLink port) is in use" \
            in same.stderr, same.stderr
        second = subprocess.Popen(_mrta("sitl", "run", str(fleet), "--speedup", "2", "--instance", "1",
                                        "--run-dir", str(tmp_path / "c")),
                                  cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert first.poll() is None, "the first fleet ended before the second started: they did not overlap"
        outs = {name: p.communicate(timeout=300) for name, p in (("first", first), ("second", second))}
    finally:
        for p in (first, second):
            if p is not None and p.poll() is None:
                p.kill()
    for name, p in (("first", first), ("second", second)):
        out, err = outs[name]
        print(name, out[-800:])
        assert p.returncode == 0, f"{name}: {err[-1500:]}"
        assert "verdict: goal met" in out and "assignment valid: True" in out
    manifest = yaml.safe_load((tmp_path / "c" / "manifest.json").read_text())
    assert {r["mavlink_udp"] for r in manifest["robots"]} == {f"127.0.0.1:{base + 100 + i}" for i in (1, 2, 3, 4)}


def test_a_port_taken_after_the_check_cannot_lose_a_robot(tmp_path):
    """Issue 31 point 10: the launcher holds each robot's MAVLink port from its check on and hands the bound socket
    to the daemon, so a program that tries to take a port between the check and the daemons' start is refused,
    and every daemon still listens on its port (lock-step here; process mode passes the same socket as an
    inherited descriptor, `mrta daemon --listen-fd`)."""
    from sitl import launcher
    f = launcher.build(shipped_fleet(tmp_path, "operator_4.yaml"), tmp_path / "run")
    run = None
    try:
        ports = {rid: r.udp_port for rid, r in f.robots.items()}
        assert all(_bound(p) for p in ports.values())          # the intruder finds every port taken
        run = launcher.Lockstep(f)
        assert not f.held                                       # every socket handed over
        for rid, d in run.daemons.items():
            assert d.link.sock.getsockname() == ("127.0.0.1", ports[rid])
        for _ in range(40):
            run.step()
        assert sorted(run.op.live_robots()) == sorted(ports)    # each daemon heard on its port
    finally:
        if run is not None:
            run.close()
        f.close()
    assert not any(_bound(p) for p in ports.values())           # and released at the end


def test_a_handed_in_socket_must_be_udp_on_the_listen_address():
    from runtime.comms.link import MavlinkLink
    from runtime.daemon_cli import _inherited
    from runtime.errors import InputError
    other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    other.bind(("127.0.0.1", 0))
    tcp = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        port = other.getsockname()[1]
        with pytest.raises(InputError, match="comms.listen: expected the socket handed in to be UDP bound to"):
            MavlinkLink(1, f"127.0.0.1:{port + 1 if port < 65535 else port - 1}", [], sock=other)
        tcp.bind(("127.0.0.1", 0))
        with pytest.raises(InputError, match="comms.listen"):
            MavlinkLink(1, f"127.0.0.1:{tcp.getsockname()[1]}", [], sock=tcp)
        link = MavlinkLink(1, f"127.0.0.1:{port}", [], sock=other)
        assert link.sock is other
        with pytest.raises(InputError, match="--listen-fd: expected an open UDP socket's descriptor, got 9999"):
            _inherited(9999)
    finally:
        other.close()
        tcp.close()
