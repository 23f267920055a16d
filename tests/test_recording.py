"""Recording (issue 36): a lock-step SITL run's run.mcap read back with the ``mcap`` reader, a Foxglove WebSocket
client subscribed during the same run, the picture redrawn from the file, and the recorder's bounds (size limit,
rotation, a full disk) and reader (files cut short, random and bit-flipped bytes) on their own."""
from __future__ import annotations

import errno
import io
import json
import logging
import shutil
import socket
import struct
import threading
import time
from collections import defaultdict

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

pytest.importorskip("foxglove")
pytest.importorskip("mcap_protobuf")

from runtime.errors import InputError  # noqa: E402
from runtime.recording import summary  # noqa: E402
from runtime.recording.read import read_messages  # noqa: E402
from runtime.recording.recorder import TOPICS, Recorder  # noqa: E402
from sitl.ports import free_port  # noqa: E402
from tests.sitl_util import worker_fleet  # noqa: E402

ROBOT_TOPICS = ("pose", "truth", "command", "path", "bumpers", "mavlink", "stats")
SUBPROTOCOL = "foxglove.sdk.v1"        # what foxglove-sdk 0.30's server speaks (the successor of foxglove.websocket.v1)


class LiveClient(threading.Thread):
    """A Foxglove WebSocket client (``websockets``): subscribes to ``topics`` as the server advertises them and
    keeps every message it gets as (topic, log time ns, payload)."""

    def __init__(self, port: int, topics: set[str]):
        super().__init__(daemon=True)
        self.port, self.topics = port, topics
        self.got: list[tuple[str, int, bytes]] = []
        self.subscribed: set[str] = set()
        self.status: list[dict] = []          # the server's other text messages (status, unadvertise ...)
        self.resubscribed = 0
        self.error: Exception | None = None
        self.stop = threading.Event()

    def run(self) -> None:
        from websockets.exceptions import ConnectionClosedOK
        from websockets.sync.client import connect

        try:
            deadline = time.monotonic() + 30
            while True:
                try:
                    ws = connect(f"ws://127.0.0.1:{self.port}", subprotocols=[SUBPROTOCOL], open_timeout=5)
                    break
                except OSError:
                    if time.monotonic() > deadline:
                        raise
                    time.sleep(0.05)
            with ws:
                subs: dict[int, str] = {}
                channel: dict[str, tuple[int, float, int]] = {}     # topic -> (channel id, when subscribed, sid)
                heard: set[str] = set()
                next_sid = 0
                while not self.stop.is_set():
                    try:
                        m = ws.recv(timeout=0.2)
                    except TimeoutError:
                        m = None
                    if isinstance(m, str):
                        d = json.loads(m)
                        if d.get("op") not in ("advertise", "serverInfo"):
                            self.status.append(d)
                        for c in d.get("channels", ()) if d.get("op") == "advertise" else ():
                            if c["topic"] in self.topics and c["topic"] not in self.subscribed:
                                channel[c["topic"]] = (c["id"], 0.0, 0)
                                self.subscribed.add(c["topic"])
                    elif m is not None and m[0] == 1:     # message data: opcode, subscription id, log time, payload
                        _, sid, ns = struct.unpack_from("<BIQ", m)
                        if sid in subs:
                            self.got.append((subs[sid], ns, m[13:]))
                            heard.add(subs[sid])
                    for topic, (cid, when, old) in channel.items():
                        # (re)subscribe a topic that has said nothing for 5 s (a subscription the server did not
                        # take while it advertised the channel)
                        if topic not in heard and time.monotonic() - when > 5.0:
                            if old:
                                del subs[old]
                                ws.send(json.dumps({"op": "unsubscribe", "subscriptionIds": [old]}))
                            sid = next_sid = next_sid + 1
                            subs[sid] = topic
                            channel[topic] = (cid, time.monotonic(), sid)
                            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": sid, "channelId": cid}]}))
                            self.resubscribed += bool(old)
        except ConnectionClosedOK:     # the server stopped at the end of the run
            pass
        except Exception as exc:       # the test reports it
            self.error = exc


class LogCapture(logging.Handler):
    def __init__(self):
        super().__init__(logging.INFO)
        self.lines: list[str] = []

    def emit(self, record):
        self.lines.append(record.getMessage())


def recorded_run(tmp) -> dict:
    """One short lock-step run of create2_4, recorded, with a live client subscribed to robot 1's pose and the
    allocation events while it runs."""
    from sitl import launcher

    port = free_port()
    client = LiveClient(port, {"/robot_1/pose", "/allocation"})
    seen = {}
    logs = LogCapture()
    logging.getLogger("mrta.daemon").addHandler(logs)

    def on_step(f):
        if not client.is_alive() and client.error is None and "started" not in seen:
            seen["started"] = True
            client.start()
            deadline = time.monotonic() + 20          # the run waits (bounded) until the client has subscribed
            while len(client.subscribed) < 2 and time.monotonic() < deadline and client.error is None:
                time.sleep(0.02)
        if f.world.t >= 5.0 and "mid_run" not in seen:
            deadline = time.monotonic() + 20
            while not {"/robot_1/pose", "/allocation"} <= {g[0] for g in client.got} and \
                    time.monotonic() < deadline and client.error is None:
                time.sleep(0.02)
            seen["mid_run"] = (f.world.t, len(client.got))

    f = launcher.build(worker_fleet(tmp, "create2_4.yaml", seed=1), tmp / "run")
    try:
        res = launcher.run_lockstep(f, record=True, live=("127.0.0.1", port), on_step=on_step)
        cycles = {rid: r.daemon.stats.cycles for rid, r in f.robots.items()}
        period = min(r.daemon.period for r in f.robots.values())
    finally:
        f.close()
        logging.getLogger("mrta.daemon").removeHandler(logs)
        client.stop.set()
        client.join(timeout=10)
    rec = read_messages(res["recording"])
    return {"res": res, "rec": rec, "cycles": cycles, "period": period, "client": client, "seen": seen,
            "logs": logs.lines, "dir": tmp / "run"}


def _by_topic(rec) -> dict[str, list]:
    out = defaultdict(list)
    for m in rec.messages:
        out[m.topic].append(m)
    return out


@pytest.mark.slow
def test_a_recorded_lock_step_run_read_back_and_watched_live(tmp_path, capsys):
    """One run for every check (a module-scoped fixture would run once per xdist worker the checks land on)."""
    run = recorded_run(tmp_path)
    _every_channel_is_there_with_its_schema_and_time_never_goes_back(run)
    _one_pose_per_robot_per_control_period(run)
    _every_award_and_every_daemon_log_line_is_in_the_recording(run)
    _the_picture_from_the_recording_is_the_one_from_the_trace(run)
    _the_summary_says_who_held_which_task(run, capsys)
    _a_live_client_gets_poses_and_allocation_events_in_order_while_the_run_goes(run)
    _the_world_shows_each_formation_target_and_who_stands_on_it(run)


def _the_world_shows_each_formation_target_and_who_stands_on_it(run):
    by = _by_topic(run["rec"])
    scenes = [_world_objects(m) for m in by["/world"]]
    last = scenes[-1]
    assert sorted(o["target"] for o in last.values()) == ["P0", "P1", "P2", "P3"]
    on = [o.get("on") for o in last.values()]
    assert None not in on and len(set(on)) == 4          # the goal: a distinct robot on every target
    assert all(o["robots"] == o["on"] for o in last.values())     # and it is the one holding it
    assert len(scenes) < len(by["/robot_1/truth"]) / 5   # when something changed, not every step


def _every_channel_is_there_with_its_schema_and_time_never_goes_back(run):
    rec, res = run["rec"], run["res"]
    assert res["goal_met"] and rec.truncated is None and rec.dropped == 0
    want = {"/tf": TOPICS["/tf"], "/world": TOPICS["/world"], "/allocation": TOPICS["/allocation"],
            "/log": TOPICS["/log"]}
    for rid in run["cycles"]:
        want.update({f"/robot_{rid}/{t}": TOPICS[f"/robot_{{id}}/{t}"] for t in ROBOT_TOPICS})
    assert {t: rec.channels.get(t) for t in want} == want
    by = _by_topic(rec)
    for topic, msgs in by.items():
        times = [m.ns for m in msgs]
        assert times == sorted(times), topic
    assert all(by[t] for t in want), [t for t in want if not by[t]]
    # sim time: the last pose is stamped with the run's last sim time
    assert by["/robot_1/truth"][-1].ns == pytest.approx(res["sim_time"] * 1e9, abs=1e3)


def _one_pose_per_robot_per_control_period(run):
    by = _by_topic(run["rec"])
    for rid, cycles in run["cycles"].items():
        for kind in ("pose", "truth", "command"):
            msgs = by[f"/robot_{rid}/{kind}"]
            assert len(msgs) == cycles, (rid, kind)
            steps = {round((b.ns - a.ns) / 1e9, 6) for a, b in zip(msgs, msgs[1:])}
            assert steps == {run["period"]}, (rid, kind, steps)


def _every_award_and_every_daemon_log_line_is_in_the_recording(run):
    by = _by_topic(run["rec"])
    events = [m.data for m in by["/allocation"]]
    committed = {(e["robot"], e["task"]) for e in events if e["event"] == "committed"}
    trace = json.loads((run["dir"] / "trace.json").read_text())
    awarded = {(r, e["task"]) for e in trace["events"] if e["what"] == "awarded" for r in e["robots"]}
    assert awarded and awarded <= committed
    assert {e["message"] for e in events if e["event"] == "sent"} >= {"Price", "RobotState", "TaskInfo"}
    # every record the daemons logged, in order, on /log
    recorded = [m.data.message for m in by["/log"]]
    it = iter(recorded)
    assert run["logs"] and all(line in it for line in run["logs"])


def _the_picture_from_the_recording_is_the_one_from_the_trace(run):
    from sitl.recording import trace_from_mcap
    from sitl.run_trace import RunTrace

    from_json = RunTrace.read(run["dir"] / "trace.json").to_dict()
    from_mcap = trace_from_mcap(run["dir"] / "run.mcap").to_dict()
    assert from_mcap == from_json
    assert from_json["events"] and all(r["samples"] for r in from_json["robots"])


def _the_summary_says_who_held_which_task(run, capsys):
    from runtime import cli

    s = summary.summarize(run["dir"] / "run.mcap")
    assert sorted(s["robots"]) == sorted(run["cycles"])
    assert all(r["poses"] == run["cycles"][rid] for rid, r in s["robots"].items())
    assert len(s["tasks"]) == 4 and all(t["held"] for t in s["tasks"].values())
    assert cli.main(["log", "summary", str(run["dir"] / "run.mcap")]) == 0
    out = capsys.readouterr().out
    assert "robot 4:" in out and "held by robot" in out and "sent: Price" in out


def _a_live_client_gets_poses_and_allocation_events_in_order_while_the_run_goes(run):
    client = run["client"]
    assert client.error is None, client.error
    t_mid, n_mid = run["seen"]["mid_run"]
    assert t_mid < run["res"]["sim_time"] and n_mid > 0         # messages arrived before the run ended
    got = defaultdict(list)
    for topic, ns, payload in client.got:
        got[topic].append((ns, payload))
    for topic in ("/robot_1/pose", "/allocation"):
        times = [ns for ns, _ in got[topic]]
        assert times and times == sorted(times), topic
    # what the client got is what the file has, message for message
    by = _by_topic(run["rec"])
    file_events = [json.dumps(m.data, sort_keys=True) for m in by["/allocation"]]
    live_events = [json.dumps(json.loads(p), sort_keys=True) for _, p in got["/allocation"]]
    it = iter(file_events)
    assert all(e in it for e in live_events)
    file_poses = {m.ns for m in by["/robot_1/pose"]}
    assert {ns for ns, _ in got["/robot_1/pose"]} <= file_poses


# ---------------------------------------------------------------------- the recorder's bounds, the reader

def _poses(rec: Recorder, n: int, t0: float = 0.0) -> None:
    for k in range(n):
        rec.pose(1, t0 + 0.05 * k, (0.01 * k, 0.0, 0.1 * k))
        rec.event(t0 + 0.05 * k, 1, "sent", "Bid", 65537, (1,), {"cost": 0.5 * k})
        rec.check()


def test_at_the_size_limit_the_recording_stops_or_rotates(tmp_path, caplog):
    stop = Recorder(tmp_path / "stop.mcap", limit=20_000, chunk_size=4096)
    _poses(stop, 2000)
    stop.close()
    assert stop.stopped and "size limit" in stop.stopped and stop.files == [tmp_path / "stop.mcap"]
    assert read_messages(tmp_path / "stop.mcap").truncated is None
    assert (tmp_path / "stop.mcap").stat().st_size < 20_000 + 3 * 4096

    rot = Recorder(tmp_path / "rot.mcap", limit=20_000, rotate=True, chunk_size=4096)
    rot.metadata("robot", {"id": "1"})
    _poses(rot, 2000)
    rot.close()
    assert rot.stopped is None and len(rot.files) >= 3
    assert rot.files[1] == tmp_path / "rot.1.mcap"
    poses = []
    for path in rot.files:
        r = read_messages(path)
        assert r.truncated is None and r.metadata["robot"] == {"id": "1"}
        assert r.channels["/robot_1/pose"] == "foxglove.PoseInFrame"
        poses += [m.ns for m in r.messages if m.topic == "/robot_1/pose"]
    assert poses == [round(0.05 * k * 1e9) for k in range(2000)]      # nothing lost between files


class FullDisk:
    """A file whose disk fills after ``room`` bytes."""

    def __init__(self, fh, room: int):
        self.fh, self.room = fh, room

    def write(self, data):
        if len(data) > self.room:
            raise OSError(errno.ENOSPC, "No space left on device")
        self.room -= len(data)
        return self.fh.write(data)

    def __getattr__(self, name):
        return getattr(self.fh, name)


def test_a_full_disk_ends_the_recording_with_one_warning_and_nothing_else(tmp_path, caplog):
    rec = Recorder(tmp_path / "full.mcap", chunk_size=2048)
    rec._file.fh = FullDisk(rec._file.fh, 10_000)
    with caplog.at_level(logging.WARNING, logger="mrta.recording"):
        _poses(rec, 3000)             # never raises
        rec.close()
    warnings = [r for r in caplog.records if r.name == "mrta.recording"]
    assert len(warnings) == 1 and "No space left on device" in warnings[0].getMessage()
    assert rec.stopped
    r = read_messages(tmp_path / "full.mcap")       # what fitted is readable; the end is missing
    assert r.truncated is not None and r.messages


def _small_recording(path) -> bytes:
    rec = Recorder(path, chunk_size=1024)
    rec.metadata("run", {"fleet": "test"})
    _poses(rec, 200)
    rec.text(1.0, logging.INFO, "mrta.daemon robot=1", "hello")
    rec.close()
    return path.read_bytes()


def test_a_recording_cut_short_reads_up_to_its_last_whole_chunk(tmp_path):
    data = _small_recording(tmp_path / "whole.mcap")
    whole = read_messages(tmp_path / "whole.mcap")
    assert whole.truncated is None and len(whole.messages) == 401
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    r = read_messages(cut)
    assert r.truncated and 0 < len(r.messages) < len(whole.messages)
    assert [m.ns for m in r.messages] == [m.ns for m in whole.messages[: len(r.messages)]]
    s = summary.summarize(cut)
    assert s["truncated"] and s["robots"][1]["poses"] > 0
    for bad, why in ((b"", "empty"), (b"not an mcap file at all", "text")):
        p = tmp_path / f"{why}.mcap"
        p.write_bytes(bad)
        with pytest.raises(InputError, match=str(p)):
            read_messages(p)
    with pytest.raises(InputError, match="missing.mcap"):
        read_messages(tmp_path / "missing.mcap")


@pytest.fixture(scope="module")
def sample(tmp_path_factory) -> bytes:
    return _small_recording(tmp_path_factory.mktemp("sample") / "s.mcap")


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.data())
def test_the_reader_never_raises_but_input_error_on_random_cut_or_bit_flipped_files(sample, tmp_path, data):
    kind = data.draw(st.sampled_from(["random", "cut", "flip"]))
    if kind == "random":
        blob = data.draw(st.binary(max_size=2000))
    elif kind == "cut":
        blob = sample[: data.draw(st.integers(0, len(sample)))]
    else:
        blob = bytearray(sample)
        for i in data.draw(st.lists(st.integers(0, len(sample) * 8 - 1), min_size=1, max_size=8)):
            blob[i // 8] ^= 1 << (i % 8)
        blob = bytes(blob)
    p = tmp_path / "x.mcap"
    p.write_bytes(blob)
    try:
        s = summary.summarize(p)          # reads it (read_messages) and tallies what it can
    except InputError as exc:
        assert str(p) in str(exc)
        return
    assert s["messages"] <= 401
    summary.print_summary(s, io.StringIO())


@pytest.mark.slow
def test_a_killed_daemon_leaves_a_readable_recording(tmp_path):
    """``mrta daemon --record`` on a real-time SITL robot (the world and devices of ``--devices-only``), killed
    with SIGKILL: the summary reads the file, at most the last chunk lost."""
    import signal
    import subprocess
    import sys

    from tests.sitl_util import ROOT, devices_only

    world, robots = devices_only(worker_fleet(tmp_path, "create2_4.yaml", seed=1), tmp_path)   # ports of its own
    daemon = None
    out = tmp_path / "robot_1.mcap"
    try:
        config = robots[0]["config"]
        daemon = subprocess.Popen([sys.executable, "-m", "runtime.cli", "daemon", config, "--record", str(out)],
                                  cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        deadline = time.monotonic() + 60         # a flush (every 2 s) has put poses on disk
        while time.monotonic() < deadline:
            assert daemon.poll() is None, daemon.stdout.read()
            if out.exists() and out.stat().st_size > 2000:
                try:
                    if read_messages(out).messages:
                        break
                except InputError:
                    pass
            time.sleep(0.2)
        time.sleep(0.5)
        daemon.send_signal(signal.SIGKILL)
        daemon.wait(timeout=10)
    finally:
        if daemon is not None and daemon.poll() is None:
            daemon.kill()
        world.send_signal(signal.SIGINT)
        world.communicate(timeout=20)
    s = summary.summarize(out)
    assert s["truncated"] is not None                      # killed: no summary section
    assert s["robots"][1]["poses"] > 0 and s["metadata"]["robot"]["id"] == "1"
    assert s["metadata"]["robot"]["clock"] == "system"
    wall = time.time()
    assert abs(s["end"] - wall) < 120                      # stamped with the system clock
    from runtime import cli
    assert cli.main(["log", "summary", str(out)]) == 0
    shutil.rmtree(tmp_path / "run", ignore_errors=True)


def test_the_shipped_foxglove_layout_is_the_one_the_code_builds():
    from runtime.recording.layout import layout_json
    from tests.sitl_util import ROOT

    shipped = (ROOT / "docs" / "foxglove_layout.json").read_text()
    assert shipped == layout_json(10), "regenerate: python -m runtime.recording.layout > docs/foxglove_layout.json"
    topics = json.loads(shipped)["content"]["items"][0]["content"]["items"][0]["content"]["config"]["topics"]
    known = {t.replace("{id}", "1") for t in TOPICS}
    assert {t for t in topics if t.startswith("/robot_1/") or not t.startswith("/robot_")} <= known


def test_the_feed_records_an_in_process_fleet_doing_its_tasks(tmp_path):
    """Three robot cores on the in-process host (no physics, no sockets), each fed to one recording: every task
    done shows as committed by its doer, done in the tables, and on the world scene."""
    import math

    from runtime.inprocess import kinematic
    from runtime.recording.feed import CoreFeed
    from runtime.tasks.goto import Goto

    f = kinematic({1: (0.0, 0.0, 0.0), 2: (2.0, 0.0, math.pi), 3: (0.0, 2.0, 0.0)}, "auction")
    rec = Recorder(tmp_path / "fleet.mcap")
    feeds = {rid: CoreFeed(rec, h.core, scene=rid == 1) for rid, h in f.robots.items()}
    f.on_output = lambda rid, out, now: feeds[rid].cycle(now, out)
    ids = f.hand_in(1, [Goto(1.0, 1.0, hold=1.0), Goto(-1.0, 0.5, hold=1.0), Goto(0.5, 2.5, hold=1.0)])
    f.run(120.0, stop=lambda fl: set(fl.done()) == set(ids))
    rec.close()
    assert set(f.done()) == set(ids)
    by = _by_topic(read_messages(tmp_path / "fleet.mcap"))
    events = [m.data for m in by["/allocation"]]
    for tid, doers in f.done().items():
        assert {(e["robot"], e["task"]) for e in events if e["event"] == "committed"} >= {(r, tid) for r in doers}
        assert any(e["event"] == "task" and e["task"] == tid and e["message"] == "done"
                   and set(e["robots"]) == set(doers) for e in events)
        assert any(e["event"] == "progress" and e["task"] == tid and e["message"] == "arrived" for e in events)
    last = by["/world"][-1].data
    states = {ent.id: dict((kv.key, kv.value) for kv in ent.metadata)["state"] for ent in last.entities
              if ent.id.startswith("task_")}
    assert states == {f"task_{tid}": "done" for tid in ids}
    assert len(by["/robot_2/pose"]) == len(by["/robot_2/command"]) > 0


@pytest.mark.parametrize("argv, says", [
    (["daemon", "robot.yaml", "--live", "nohost"], "--live: expected HOST:PORT"),
    (["daemon", "robot.yaml", "--record", "x.mcap", "--record-limit", "0"], "--record-limit: expected a number > 0"),
    (["daemon", "robot.yaml", "--record", "/no/such/folder/x.mcap"], "--record /no/such/folder/x.mcap: expected"),
    (["sitl", "run", "create2_4", "--live", "127.0.0.1:99999"], "--live: expected HOST:PORT"),
    (["log", "summary", "missing.mcap"], "missing.mcap: expected a recording"),
])
def test_bad_recording_options_are_one_line_and_exit_2(argv, says, capsys, tmp_path, monkeypatch):
    from runtime import cli

    monkeypatch.chdir(tmp_path)
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err


def test_a_live_address_in_use_is_one_line_and_the_file_is_closed(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        with pytest.raises(InputError, match=f"--live 127.0.0.1:{port}: expected an address free to serve on"):
            Recorder(tmp_path / "x.mcap", live=("127.0.0.1", port))
    assert read_messages(tmp_path / "x.mcap").truncated is None          # closed: a whole (empty) recording


def _world_objects(msg) -> dict[str, dict]:
    return {ent.id: {**{kv.key: kv.value for kv in ent.metadata}, "height": ent.cylinders[0].size.z,
                     "text": ent.texts[0].text} for ent in msg.data.entities if ent.id.startswith("task_")}


def test_foraging_objects_on_the_world_show_weight_left_and_carriers_and_change_only_when_they_change(tmp_path):
    """The foraging scenario's objects as /world entities, from a FleetRecording stepped by hand (a stub operator,
    no physics): the weight and carriers a leader reports (DrLeaderAlive: left, members) show on the object, its
    disc shrinks with the weight left, it turns done, and steps that change nothing write no /world message."""
    from types import SimpleNamespace

    from runtime import config as C
    from runtime.allocation.dr.messages import DrLeaderAlive
    from sitl import fleet_config as FC
    from sitl.recording import LOOK_PERIOD, FleetRecording
    from sitl.run_trace import RunTrace, TaskMark
    from sitl.scenarios.foraging import Scenario

    fleet = FC.load_fleet("configs/fleets/foraging_4.yaml")
    world = C.load_world(fleet.world)
    scenario = Scenario(fleet, world)
    o1, o2 = scenario.handovers()
    o1.task_ids, o2.task_ids = [65537], [65538]
    trace = RunTrace(world=world)
    for h, tid in ((o1, 65537), (o2, 65538)):
        trace.tasks[tid] = TaskMark(tid, "transport", h.items[0].x, h.items[0].y, h.labels[0])
    gcs = SimpleNamespace(robots={rid: SimpleNamespace(tasks=()) for rid in (1, 2, 3, 4)})
    op = SimpleNamespace(trace=trace, gcs=gcs, live_robots=lambda: [1, 2, 3, 4], handovers=[o1, o2], fleet=SimpleNamespace(robots={1: 0, 2: 0, 3: 0, 4: 0}),
                         done_by={}, done_at={}, driven={})
    robots = {rid: SimpleNamespace(base_type="pioneer", radius=0.25) for rid in (1, 2, 3, 4)}
    f = SimpleNamespace(fleet=SimpleNamespace(source="foraging_4.yaml", world=fleet.world), robots=robots,
                        withdrawn=set(), true_pose=lambda rid: (float(rid), 0.0, 0.0), scenario=scenario)
    fr = FleetRecording(f, tmp_path / "run.mcap")
    try:
        t = 0.0
        for _ in range(5):                              # nothing changes: one /world message
            t += 0.05
            fr.step(t, op)
        gcs.robots[3].tasks = (65537,)
        trace.event(t, "awarded", 65537, (3,))
        t += 0.05
        fr.step(t, op)
        fr._watch_message(3, DrLeaderAlive(3, 0, 65537, 10.0, 6.0, 6.0, 1.0, 1.0, 1.0, (3, 4)))
        t += 0.05
        fr.step(t, op)
        for _ in range(int(LOOK_PERIOD / 0.05) + 2):      # the same report again, nothing else: no message
            fr._watch_message(3, DrLeaderAlive(3, 0, 65537, 10.0, 6.0, 6.0, 1.0, 1.0, 1.0, (3, 4)))
            t += 0.05
            fr.step(t, op)
        trace.event(t, "done", 65537, (3, 4))
        t += 0.05
        fr.step(t, op)
    finally:
        fr.tap.detach()
        fr.rec.close()
    scenes = [_world_objects(m) for m in _by_topic(read_messages(tmp_path / "run.mcap"))["/world"]]
    assert len(scenes) == 4
    first, held, carried, done = scenes
    assert first["task_65537"]["state"] == "open" and first["task_65537"]["object"] == "O1"
    assert first["task_65537"]["weight"] == "16" and "left" not in first["task_65537"]
    assert held["task_65537"]["state"] == "held" and held["task_65537"]["robots"] == "3"
    assert carried["task_65537"]["left"] == "10" and carried["task_65537"]["robots"] == "3,4"
    assert "10/16 wu" in carried["task_65537"]["text"] and "R3+R4" in carried["task_65537"]["text"]
    assert first["task_65537"]["height"] > carried["task_65537"]["height"] > 0
    assert done["task_65537"]["state"] == "done" and "left" not in done["task_65537"]
    assert all(s["task_65538"]["state"] == "open" for s in scenes)


@pytest.mark.slow
def test_one_live_view_shows_a_process_fleet_whole(tmp_path):
    """`mrta sitl run --live` without --lockstep (two daemon processes, two short waypoints): a Foxglove WebSocket
    client on the launcher's one server gets each robot's poses and allocation events (relayed by the daemons
    under /robot_N/...), and from the first one it got, every one the robot recorded in robot_N.mcap, in order
    and without a gap, up to the last one it got."""
    from sitl import launcher
    from tests.test_sitl_fleet import _fleet_copy

    tasks = [{"kind": "goto", "x": x, "y": 1.0, "hold": 0.5} for x in (-1.0, 1.0)]
    robots = [{"id": 1, "start": [-1.0, 0.0, 1.5708]}, {"id": 2, "start": [1.0, 0.0, 1.5708]}]
    f = launcher.build(_fleet_copy(tmp_path, robots=robots, scenario={"type": "mission", "tasks": tasks}),
                       tmp_path / "run")
    port = free_port()
    topics = {f"/robot_{rid}/{t}" for rid in (1, 2) for t in ("pose", "allocation")}
    client = LiveClient(port, topics)
    client.start()
    try:
        res = launcher.run_processes(f, 2.0, timeout=40, record=True, live=("127.0.0.1", port))
    finally:
        f.close()
        client.stop.set()
        client.join(timeout=10)
    assert client.error is None, client.error
    assert res["goal_met"], res["verdict"]
    got = defaultdict(list)
    for topic, ns, payload in client.got:
        got[topic].append((ns, payload))
    assert client.subscribed == topics and all(got[t] for t in topics), \
        ({t: len(got[t]) for t in topics}, client.status[:5], client.resubscribed)
    run_mcap = read_messages(tmp_path / "run" / "run.mcap")
    assert not any(t.startswith("/robot_") and not t.endswith("/truth") for t in run_mcap.channels)
    for rid in (1, 2):
        by = _by_topic(read_messages(tmp_path / "run" / f"robot_{rid}.mcap"))
        poses = [m.ns for m in by[f"/robot_{rid}/pose"]]
        live = [ns for ns, _ in got[f"/robot_{rid}/pose"]]
        start = poses.index(live[0])
        assert live == poses[start:start + len(live)], rid
        events = [json.dumps(m.data, sort_keys=True) for m in by["/allocation"]]
        live = [json.dumps(json.loads(p), sort_keys=True) for _, p in got[f"/robot_{rid}/allocation"]]
        start = events.index(live[0])
        assert live == events[start:start + len(live)], rid
        assert any(json.loads(e)["event"] == "sent" for e in live), rid


def _relay_pair(tmp_path):
    """A daemon-side Recorder relaying to a launcher-side Recorder's RelayServer (both in this process)."""
    from runtime.recording.relay import RelayServer

    launcher_rec = Recorder(tmp_path / "run.mcap")
    seen = []
    server = RelayServer(launcher_rec, on_message=lambda rid, topic, payload: seen.append((rid, topic)))
    robot_rec = Recorder(tmp_path / "robot_3.mcap", relay=server.address, robot_id=3)
    return launcher_rec, server, robot_rec, seen


def test_the_relay_carries_a_daemons_channels_whole_and_in_order_and_not_into_the_launchers_file(tmp_path):
    launcher_rec, server, robot_rec, seen = _relay_pair(tmp_path)
    try:
        for k in range(300):
            robot_rec.pose(3, 0.05 * k, (0.01 * k, 0.0, 0.1))
            robot_rec.event(0.05 * k, 3, "sent", "Bid", 65537, (3,), {"cost": 0.5 * k})
            robot_rec.check()
            server.poll()
        robot_rec.text(15.0, logging.INFO, "mrta.daemon robot=3", "done")
        robot_rec.close()
        deadline = time.monotonic() + 10
        while server.peers or not server.messages and time.monotonic() < deadline:
            server.poll()
            time.sleep(0.01)
    finally:
        server.close()
        launcher_rec.close()
    assert server.messages == 601 and server.dropped == 0
    assert [t for _, t in seen[:2]] == ["/robot_3/pose", "/robot_3/allocation"] and seen[-1] == (3, "/robot_3/log")
    assert {t for _, t in seen} == set(launcher_rec._relayed)
    assert read_messages(tmp_path / "run.mcap").channels == {}        # the daemon's own file has them
    assert len(read_messages(tmp_path / "robot_3.mcap").messages) == 601


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_the_relay_receiver_never_raises_on_random_cut_or_bit_flipped_streams(tmp_path, data):
    """What reaches the launcher's relay port: a real stream cut anywhere, bit-flipped, or random bytes.  The
    receiver never raises; what it cannot read it counts or ends the connection."""
    from runtime.recording.relay import CHANNEL, MESSAGE, RelayServer, _Peer, frame

    rec = Recorder(None)
    try:
        server = RelayServer(rec)
        good = frame(CHANNEL, 1, json.dumps({"robot": 2, "topic": "/allocation", "encoding": "json",
                                             "schema": "mrta.AllocationEvent", "schema_encoding": "jsonschema",
                                             "schema_data": ""}).encode())
        good += b"".join(frame(MESSAGE, 1, struct.pack("<Q", k) + b'{"robot":2}') for k in range(5))
        kind = data.draw(st.sampled_from(["cut", "flip", "random"]))
        if kind == "cut":
            stream = good[:data.draw(st.integers(0, len(good)))]
        elif kind == "flip":
            stream = bytearray(good)
            for _ in range(data.draw(st.integers(1, 8))):
                i = data.draw(st.integers(0, len(stream) - 1))
                stream[i] ^= 1 << data.draw(st.integers(0, 7))
            stream = bytes(stream)
        else:
            stream = data.draw(st.binary(max_size=400))
        a, b = socket.socketpair()
        try:
            b.setblocking(False)
            peer = _Peer(b)
            server.peers.append(peer)
            a.sendall(stream)
            a.close()
            for _ in range(5):
                server.poll()
            assert peer not in server.peers            # the stream ended: the connection is closed
            assert server.messages + server.dropped <= 5 + len(stream)
        finally:
            a.close()
            b.close()
        server.close()
    finally:
        rec.close()


def test_log_replay_sends_the_recorded_frames_to_a_ground_station_at_their_pace(tmp_path, capsys):
    """`mrta log replay FILE.mcap --to HOST:PORT --speed X`: a pymavlink listener on loopback gets every frame two
    robots sent, in the recorded order, each robot's heartbeats with their sequence numbers, and nothing they
    received; the replay takes at least the recorded span over X."""
    from pymavlink import mavutil
    from pymavlink.dialects.v20 import common

    from runtime import cli

    rec = Recorder(tmp_path / "robot.mcap", mavlink=True)
    packers = {rid: common.MAVLink(None, srcSystem=rid, srcComponent=1) for rid in (1, 2)}
    sent = []
    for k in range(20):
        for rid, mav in packers.items():
            msg = mav.heartbeat_encode(common.MAV_TYPE_GROUND_ROVER, common.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, k, 4)
            data = msg.pack(mav)
            mav.seq = (mav.seq + 1) % 256
            rec.frame(rid, 0.05 * k, "tx", data, ("127.0.0.1", 14550))
            rec.frame(rid, 0.05 * k, "rx", b"\xfd\x00junk", ("127.0.0.1", 14601))
            sent.append((rid, k))
    rec.close()
    port = free_port(udp=True)
    conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
    try:
        start = time.monotonic()
        assert cli.main(["log", "replay", str(tmp_path / "robot.mcap"), "--to", f"127.0.0.1:{port}",
                         "--speed", "4"]) == 0
        took = time.monotonic() - start
        got = []
        for _ in range(len(sent) + 5):
            m = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=2 if len(got) < len(sent) else 0.2)
            if m is None:
                break
            got.append((m.get_srcSystem(), m.custom_mode, m.get_seq()))
    finally:
        conn.close()
    assert got == [(rid, k, k) for rid, k in sent]
    assert took >= 0.95 * 19 * 0.05 / 4
    assert "sent 40 frames" in capsys.readouterr().out


@pytest.mark.parametrize("argv, says", [
    (["--to", "nohost"], "--to: expected HOST:PORT"),
    (["--to", "127.0.0.1:9", "--speed", "0"], "--speed"),
])
def test_bad_replay_options_are_one_line_and_exit_2(argv, says, capsys, tmp_path):
    from runtime import cli

    rec = Recorder(tmp_path / "r.mcap", mavlink=True)
    rec.frame(1, 0.0, "tx", b"\xfe\x00", None)
    rec.close()
    assert cli.main(["log", "replay", str(tmp_path / "r.mcap"), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0]


def test_raw_frames_batched_by_half_seconds_read_back_frame_for_frame(tmp_path):
    """The frames a link tapped over half a second (FRAME_BATCH) are one message a robot (mrta.MavlinkFrames);
    read back, each frame has its own time, direction, address and bytes, in time order across robots; an entry
    that does not parse is skipped and counted; a file of the earlier one-frame-a-message kind reads too."""
    from runtime.recording import replay
    from runtime.recording.recorder import FRAME_BATCH

    rec = Recorder(tmp_path / "r.mcap", mavlink=True)
    want = []
    for k in range(12):                     # cycles of 0.1 s: frames held at 0.0 s go out at 0.5 s, the next at 1.1
        rec.stamp(0.1 * k)
        for rid in (1, 2):
            for d, addr in (("tx", ("127.0.0.1", 14550)), ("rx", None)):
                data = bytes([0xFD, k, rid]) + d.encode()
                rec.frame(rid, 0.1 * k + 0.001 * rid, d, data, addr)
                want.append((round((0.1 * k + 0.001 * rid) * 1e9), rid, data))
        rec.check()
    rec.close()
    msgs = [m for m in read_messages(tmp_path / "r.mcap").messages if m.kind == "mavlink"]
    assert FRAME_BATCH == 0.5 and [(m.robot, len(m.data["frames"])) for m in msgs] == [(1, 12), (2, 12)] * 2
    assert {m.schema for m in msgs} == {"mrta.MavlinkFrames"} and msgs[0].ns == round(0.5e9)
    assert msgs[0].data["frames"][1] == {"ns": round(0.001e9), "direction": "rx", "address": "",
                                         "frame": "fd00017278"}
    got, skipped = replay.frames(tmp_path / "r.mcap", rx=True)
    assert skipped == 0 and got == sorted(want, key=lambda w: w[0])
    assert replay.frames(tmp_path / "r.mcap", robots=[1])[0] == [w for w in sorted(want) if w[1] == 1 and
                                                                  w[2].endswith(b"tx")]
    # the earlier format, and entries that do not parse
    import foxglove

    ctx = foxglove.Context()
    writer = foxglove.open_mcap(tmp_path / "old.mcap", context=ctx)
    ch = foxglove.Channel("/robot_3/mavlink", context=ctx, message_encoding="json",
                          schema=foxglove.Schema(name="mrta.MavlinkFrame", encoding="jsonschema", data=b"{}"))
    ch.log(b'{"robot":3,"direction":"tx","address":"","frame":"fe00"}', log_time=5)
    ch.log(b'{"robot":3,"frames":[{"ns":7,"direction":"tx","frame":"zz"},3,{"ns":9,"direction":"tx","frame":"fe"}]}',
           log_time=9)
    writer.close()
    assert replay.frames(tmp_path / "old.mcap") == ([(5, 3, b"\xfe\x00"), (9, 3, b"\xfe")], 2)


def test_replaying_a_recording_without_frames_names_the_file(tmp_path, capsys):
    from runtime import cli

    rec = Recorder(tmp_path / "r.mcap")
    rec.pose(1, 0.0, (0.0, 0.0, 0.0))
    rec.close()
    assert cli.main(["log", "replay", str(tmp_path / "r.mcap"), "--to", "127.0.0.1:9"]) == 2
    err = capsys.readouterr().err.strip()
    assert str(tmp_path / "r.mcap") in err and "expected raw MAVLink frames" in err


def test_a_laser_revolution_is_one_laser_scan_at_one_degree_steps(tmp_path):
    """A laser's (bearing, distance) pairs become one foxglove.LaserScan over [-pi, pi) in 1-degree bins: each
    reading in its bin, the nearest where two share one, NaN where none came back (the readings stay points on
    /robot_N/ranges too)."""
    import math
    rec = Recorder(tmp_path / "scan.mcap")
    readings = [(math.radians(a), 2.0 + a / 1000.0) for a in range(0, 360, 2)]          # every other degree
    readings += [(math.radians(90.2), 1.0), (math.radians(-180.0), 3.0)]                  # 90 deg twice; -180 = 180
    rec.scan(3, 1.5, readings + [(math.nan, 1.0), (0.0, math.inf)])                       # not finite: left out
    rec.close()
    r = read_messages(tmp_path / "scan.mcap")
    assert r.channels["/robot_3/scan"] == TOPICS["/robot_{id}/scan"] == "foxglove.LaserScan"
    (m,) = [m for m in r.messages if m.topic == "/robot_3/scan"]
    scan = m.data
    assert scan.frame_id == "robot_3" and len(scan.ranges) == 360
    assert scan.start_angle == pytest.approx(-math.pi) and scan.end_angle == pytest.approx(math.pi - math.pi / 180)
    at = {round(math.degrees(scan.start_angle) + i): d for i, d in enumerate(scan.ranges)}     # -180 .. 179
    assert at[0] == pytest.approx(2.0) and at[90] == pytest.approx(1.0) and at[-180] == pytest.approx(2.18)
    assert at[44] == pytest.approx(2.044) and math.isnan(at[45]) and at[-2] == pytest.approx(2.358)


_CLASSES: dict = {}


def _protobuf_class(schema):
    """The protobuf message class of a foxglove schema (its FileDescriptorSet), built once."""
    if schema.name not in _CLASSES:
        from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

        pool = descriptor_pool.DescriptorPool()
        for fd in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
            pool.Add(fd)
        _CLASSES[schema.name] = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
    return _CLASSES[schema.name]


@settings(max_examples=40, deadline=None)
@given(x=st.floats(-1e6, 1e6), y=st.floats(-1e6, 1e6), yaw=st.floats(-10.0, 10.0),
       ns=st.integers(0, (2 ** 32 - 1) * 10 ** 9), rids=st.lists(st.integers(1, 300), min_size=1, max_size=4))
def test_poses_encoded_here_decode_as_the_sdks_own_messages(x, y, yaw, ns, rids):
    """foxglove.PoseInFrame and FrameTransforms are encoded by the recorder (a pose every cycle: the SDK's message
    objects cost too much); the bytes decode to the fields the SDK's own messages carry."""
    import math

    import foxglove.messages as m

    from runtime.recording import recorder as R

    def decode(schema, data):
        return _protobuf_class(schema.get_schema()).FromString(data)

    vec, quat = R._pose_pb(x, y, yaw)
    ts = R._field(1, R._timestamp_pb(ns))
    mine = decode(m.PoseInFrame, ts + R._WORLD_PB + R._POSE_HEAD + vec + R._QUAT_IN_POSE + quat)
    stamp = m.Timestamp(sec=ns // 10 ** 9, nsec=ns % 10 ** 9)
    v = m.Vector3(x=x, y=y, z=0.0)
    q = m.Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2.0), w=math.cos(yaw / 2.0))
    sdk = decode(m.PoseInFrame, m.PoseInFrame(timestamp=stamp, frame_id="world",
                                              pose=m.Pose(position=v, orientation=q)).encode())
    assert mine == sdk
    tfs = b"".join(R._field(1, ts + R._WORLD_PB + R._field(3, f"robot_{r}".encode()) + R._TRANSLATION + vec
                            + R._ROTATION + quat) for r in rids)
    sdk = m.FrameTransforms(transforms=[m.FrameTransform(timestamp=stamp, parent_frame_id="world",
                                                         child_frame_id=f"robot_{r}", translation=v, rotation=q)
                                        for r in rids])
    assert decode(m.FrameTransforms, tfs) == decode(m.FrameTransforms, sdk.encode())
