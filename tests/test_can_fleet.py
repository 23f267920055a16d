"""CAN robots in the SITL: the can_2 fleet reaches its formation (lock-step, repeatable; and as processes over
the socketcand hub), python-can's stock logger records a running robot's drive traffic through the hub, and a
ground station sees a drive fault and resets it."""
from __future__ import annotations

import math
import os
import signal
import struct
import subprocess
import sys
import time

import can
import pytest
from pymavlink import mavutil

from runtime.drivers import cia402_protocol as P
from sitl import can_hub, launcher
from tests.sitl_util import StockGcs, shipped_fleet

MAV = mavutil.mavlink


def _run(tmp_path, name="run", **kw):
    f = launcher.build(shipped_fleet(tmp_path, "can_2.yaml"), tmp_path / name, **kw)
    faults = set()

    def watch(fleet):
        for r in fleet.robots.values():
            faults.update(r.daemon.base.sensors.faults)
    try:
        res = launcher.run_lockstep(f, timeout=60, on_step=watch, picture=False)
        poses = {rid: f.true_pose(rid) for rid in f.robots}
    finally:
        f.close()
    return res, poses, faults


@pytest.mark.slow
def test_can_2_reaches_its_formation_in_lockstep_and_runs_repeat(tmp_path):
    res, poses, faults = _run(tmp_path, "a")
    assert res["goal_met"] and res["valid"], res["verdict"]
    assert faults == set()
    assert res["sim_time"] < 30
    again, poses2, _ = _run(tmp_path, "b")
    assert again["sim_time"] == res["sim_time"] and poses2 == poses          # frames never late by a thread's turn
    assert can_hub._shared is None                                           # the last device stopped the hub


@pytest.mark.slow
def test_can_2_reaches_its_formation_with_daemon_processes(tmp_path):
    f = launcher.build(shipped_fleet(tmp_path, "can_2.yaml"), tmp_path / "run")
    try:
        manifest = __import__("json").loads(f.manifest_path.read_text())
        for r in manifest["robots"]:
            assert r["base"]["interface"] == "socketcand" and r["base"]["channel"] == f"can{r['id']}"
            assert r["base"]["host"] == "127.0.0.1" and r["base"]["port"] == f.robots[1].base_dev.hub.port
        res = launcher.run_processes(f, speedup=4.0, timeout=60)
    finally:
        f.close()
    assert res["goal_met"], res["verdict"]
    stats = launcher.daemon_stats(f)
    for rid in f.robots:
        assert "base fault" not in (f.run_dir / f"robot_{rid}.log").read_text()
        base = stats[rid]["base"]
        assert base["frames"] > 500 and base["extra"]["fault_stops"] == 0 and base["extra"]["malformed"] == 0


# ----------------------------------------------------------------------------- python -m can.logger
@pytest.mark.slow
def _default_sigint():
    """In the logger's process: SIGINT at its default, whatever this process left it at (an ignored signal is
    inherited, and Python keeps it ignored), so the logger's Ctrl-C stop works as in a terminal."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def test_the_stock_can_logger_records_a_running_robot_through_the_hub(tmp_path):
    f = launcher.build(shipped_fleet(tmp_path, "can_2.yaml"), tmp_path / "run")
    hub = f.robots[1].base_dev.hub
    log_path = tmp_path / "can1.log"
    logger = subprocess.Popen([sys.executable, "-m", "can.logger", "-i", "socketcand", "-c", "can1",
                               "--bus-kwargs", f"host={hub.host}", f"port={hub.port}", "-f", str(log_path)],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env={**os.environ},
                              preexec_fn=_default_sigint)
    run = None
    try:
        deadline = time.monotonic() + 30
        while hub.listeners("can1") == 0:
            assert logger.poll() is None and time.monotonic() < deadline, logger.stdout.read().decode()
            time.sleep(0.02)
        time.sleep(can_hub.RAW_GRACE + 0.1)               # the logger has read its < ok >
        run = launcher.Lockstep(f)                        # the daemons open their drives now
        while f.world.t < 3.0:
            run.step()
        time.sleep(0.3)
    finally:
        try:
            logger.send_signal(signal.SIGINT)
            try:
                out = logger.communicate(timeout=20)[0].decode()
            except subprocess.TimeoutExpired:          # never leave it (and the shared hub) behind for the next test
                logger.kill()
                out = logger.communicate()[0].decode()
                raise AssertionError(f"can.logger did not stop within 20 s of SIGINT: {out[-300:]}") from None
        finally:
            if run is not None:
                run.close()
            f.close()
    frames = [(m.arbitration_id, bytes(m.data)) for m in can.LogReader(str(log_path))]
    assert frames, out
    kinds = {}
    for i, d in frames:
        k = P.classify(i, d)
        assert k is not None, (hex(i), d.hex())
        kinds.setdefault(k, []).append(d)
    # NMT from the master: pre-operational, then start, for both drives
    assert kinds[("nmt", 1)][:2] == [bytes([0x80, 1]), bytes([0x01, 1])]
    assert kinds[("nmt", 2)][:2] == [bytes([0x80, 2]), bytes([0x01, 2])]
    # RPDO1: controlwords 0x06, 0x07, 0x0F, then 0x0F with targets; TPDO1: the statusword answers
    cws = [struct.unpack_from("<H", d)[0] for d in kinds[("rpdo", 1)]]
    assert cws[:3] == [0x06, 0x07, 0x0F] and set(cws[3:]) == {0x0F}
    states = [P.state_of(struct.unpack_from("<H", d)[0]) for d in kinds[("tpdo", 1)] if len(d) == 3]
    assert [s for i, s in enumerate(states) if i == 0 or s != states[i - 1]][:4] == \
        ["SWITCH ON DISABLED", "READY TO SWITCH ON", "SWITCHED ON", "OPERATION ENABLED"]
    # TPDO2 (position, velocity actual) every 20 ms of sim time; heartbeats both ways
    motion = [d for d in kinds[("tpdo", 1)] if len(d) == 8]
    assert len(motion) > 100
    positions = [struct.unpack_from("<i", d)[0] for d in motion]
    assert positions[-1] != positions[0]                  # the wheel turned
    assert set(kinds[("heartbeat", 1)][-5:]) == {bytes([P.HB_OPERATIONAL])}
    assert set(kinds[("heartbeat", 127)]) == {bytes([P.HB_OPERATIONAL])} and len(kinds[("heartbeat", 127)]) >= 25
    assert ("sdo_rx", 1) in kinds and ("sdo_tx", 1) in kinds


# ----------------------------------------------------------------------------- the ground station
def _health_ok(m) -> bool:
    return bool(m.onboard_control_sensors_health & MAV.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS)


@pytest.mark.slow
def test_the_ground_station_sees_a_drive_fault_and_resets_it(tmp_path):
    f = launcher.build(shipped_fleet(tmp_path, "can_2.yaml"), tmp_path / "run")
    run = launcher.Lockstep(f)
    gcs = StockGcs(f.robots[1].udp_port, 1, f.key)
    daemon = run.daemons[1]
    try:
        while f.world.t < 3.0:
            run.step()
        gcs.heartbeat()
        seen = gcs.wait(lambda m: m.get_type() == "SYS_STATUS" and m.get_srcSystem() == 1, 5.0, run.step)
        assert seen and _health_ok(seen[-1])
        f.robots[1].base_dev.drives["left"].silence()
        t_cut = f.world.t
        texts = gcs.wait(lambda m: m.get_type() == "STATUSTEXT" and "base fault" in m.text, 10.0, run.step)
        assert texts and texts[-1].text == "base fault: left_drive_silent"
        assert texts[-1].severity == MAV.MAV_SEVERITY_CRITICAL and f.world.t - t_cut < 0.6
        status = gcs.wait(lambda m: m.get_type() == "SYS_STATUS" and not _health_ok(m), 5.0, run.step)
        assert status and not _health_ok(status[-1])
        assert not daemon.core.node.armed and not daemon.core.agent.commitments           # disarmed: its task went back
        right = f.robots[1].base_dev.drives["right"]
        assert right.motor == 0.0 and right.state == P.QUICK_STOP
        gcs.heartbeat()
        hb = gcs.wait(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1, 5.0, run.step)
        assert not hb[-1].base_mode & MAV.MAV_MODE_FLAG_SAFETY_ARMED

        f.robots[1].base_dev.drives["left"].silence(False)                       # the cable is back
        gcs.mav.command_long_send(1, 1, MAV.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        acks = gcs.wait(lambda m: m.get_type() == "COMMAND_ACK", 5.0, run.step)
        assert acks and acks[-1].result == MAV.MAV_RESULT_ACCEPTED
        cleared = gcs.wait(lambda m: m.get_type() == "STATUSTEXT" and m.text == "base faults cleared", 10.0, run.step)
        assert cleared, [m.text for m in gcs.got if m.get_type() == "STATUSTEXT"]
        assert any(m.get_type() == "STATUSTEXT" and m.text == "base fault reset requested" for m in gcs.got)
        assert daemon.core.node.armed and daemon.base.sensors.faults == ()
        gcs.heartbeat()
        ok = gcs.wait(lambda m: m.get_type() == "SYS_STATUS" and m.get_srcSystem() == 1 and _health_ok(m), 5.0,
                      run.step)
        assert ok
        from sitl.operator import RunView
        while f.world.t < 60 and not f.scenario.goal(RunView(run.op)):          # and the formation completes
            run.step()
        assert f.scenario.goal(RunView(run.op))
        assert math.hypot(*daemon.core.velocity()) < 0.05
    finally:
        gcs.close()
        run.close()
        f.close()
