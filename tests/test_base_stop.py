"""A base whose daemon dies (SIGKILL) or freezes (SIGSTOP) mid-drive stands still within a stated bound, on every
base: a Create by its stop guard (the OI has no watchdog), a Pioneer by its ARCOS watchdog (2 s; over TCP a kill
also closes the connection, which ends the session at once), a CAN base by its drives' heartbeat consumer (3
heartbeat periods, 0.3 s).  The daemon is ``tests/stop_rig.py``'s child: the base loop of ``mrta daemon`` with its
stop guard, in a process of its own."""
from __future__ import annotations

import signal

import pytest

from tests.stop_rig import StopRig

# (base, signal, bound in s: the mechanism's own time; the assertion allows LOAD_SLACK more for a loaded machine)
CASES = [
    ("create_pty", signal.SIGKILL, 0.05),    # the guard sees the heartbeat pipe close
    ("create_pty", signal.SIGSTOP, 0.5),     # the guard's bound (base.guard)
    ("arcos_pty", signal.SIGKILL, 2.0),      # the robot's watchdog
    ("arcos_tcp", signal.SIGKILL, 0.05),     # the connection closes: the server ends the session
    ("arcos_tcp", signal.SIGSTOP, 2.0),
    ("cia402", signal.SIGKILL, 0.3),         # the drives' heartbeat consumer
    ("cia402", signal.SIGSTOP, 0.3),
]
LOAD_SLACK = 3.0


@pytest.mark.slow
def test_the_body_stands_still_after_its_daemon_dies_or_freezes():
    """Every case at once (a child each, side by side: the wall time of the slowest, not of their sum)."""
    rigs = []
    try:
        for kind, _, _ in CASES:
            rigs.append(StopRig(kind))
        took = StopRig.standstill_all(rigs, [sig for _, sig, _ in CASES])
        for (kind, sig, bound), t in zip(CASES, took):
            assert t is not None, f"{kind}: still moving 10 s after {sig.name}"
            assert t < bound + LOAD_SLACK, (kind, sig.name, t)
        for (kind, sig, _), r in zip(CASES, rigs):
            assert r.stays_still(0.3), (kind, sig.name)
            assert not r.errors, (kind, sig.name, r.errors)
    finally:
        errs = [r.close() for r in rigs]
    for (kind, sig, _), err in zip(CASES, errs):
        assert "Traceback" not in err, err
        if kind == "create_pty":                               # one line per episode
            assert err.count("daemon silent") == (sig == signal.SIGSTOP), err
            assert err.count("daemon gone") == 1, err          # (a frozen child is killed at the end)


def test_the_daemon_beats_its_guard_and_a_silent_or_closed_pipe_stops_the_create():
    """The daemon's own wiring, in this process: ``start_guard`` starts the guard on the base's port, each step
    beats it; a daemon that stops stepping has its Create stopped within the bound, one that drives again moves
    it again; a pipe closed without goodbye (what the kernel does for a dead daemon) leaves the OI in Passive."""
    import time

    from runtime import config as C
    from runtime.daemon import Daemon
    from sitl.devices.create_oi import CreateOIDevice
    from tests.fakes import FakeBody

    body = FakeBody()
    dev = CreateOIDevice(body)
    cfg = C.from_dict(C.RobotConfig, {"base": {"port": dev.path, "guard": 0.2}, "gps": {"enabled": False},
                                      "comms": {"listen": "127.0.0.1:0", "gcs": None},
                                      "localization": {"initial_pose": [0, 0, 0]}})
    d = Daemon(cfg)
    t0 = time.monotonic()

    def serve(seconds, drive=False, until=None) -> bool:
        """Serve the emulator (and step the daemon if ``drive``) for ``seconds``, or until ``until()`` holds."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            now = time.monotonic() - t0
            dev.service(now)
            if drive:
                d.step(now)
                d.base.set_velocity(0.2, 0.0, now)
            if until is not None and until():
                return True
            time.sleep(0.01)
        return until is None

    def moving():
        return body.cmd != (0.0, 0.0)

    try:
        d.open(0.0)
        d.start_guard()
        assert d.guard is not None and d.guard.alive()
        assert serve(5.0, drive=True, until=moving)
        frozen = time.monotonic()                   # no steps, no beats from here
        assert serve(5.0, until=lambda: not moving())
        assert time.monotonic() - frozen >= 0.15 and dev.mode_name == "safe"   # not well before the bound
        assert serve(5.0, drive=True, until=moving)                             # awake again: it drives
        d.guard.close(goodbye=False)                # the pipe's end as at a death
        assert serve(5.0, until=lambda: not moving() and dev.mode_name == "passive")
    finally:
        d.close()
        dev.close()


@pytest.mark.parametrize("base, expected", [
    ("create_oi", bytes([145, 0, 0, 0, 0, 128])),                  # Drive Direct 0 0, Start (Passive)
    ("arcos", None),
])
def test_stop_base_writes_the_final_stop_on_the_port(tmp_path, capsys, base, expected):
    """`mrta stop-base ROBOT.yaml` (systemd's ExecStopPost) writes the base's final stop once and exits 0."""
    import os
    import tty

    import yaml

    from runtime.cli import main
    from runtime.drivers import arcos_protocol as A

    if expected is None:
        expected = A.vel(0) + A.rvel(0) + A.stop() + A.close()
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        path = tmp_path / "robot.yaml"
        path.write_text(yaml.safe_dump({"base": {"type": base, "port": os.ttyname(slave)}}))
        assert main(["stop-base", str(path)]) == 0
        os.set_blocking(master, False)
        assert os.read(master, 100) == expected
    finally:
        os.close(master)
        os.close(slave)
    assert "sent the" in capsys.readouterr().out


def test_stop_base_on_a_can_base_sends_nothing_and_a_bad_port_is_one_line(tmp_path, capsys):
    import yaml

    from runtime.cli import main

    path = tmp_path / "can.yaml"
    path.write_text(yaml.safe_dump({"base": {"type": "cia402", "interface": "virtual", "channel": "x"}}))
    assert main(["stop-base", str(path)]) == 0
    assert "nothing sent" in capsys.readouterr().out
    path.write_text(yaml.safe_dump({"base": {"type": "create_oi", "port": "/dev/no-such-create"}}))
    assert main(["stop-base", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "/dev/no-such-create" in err
