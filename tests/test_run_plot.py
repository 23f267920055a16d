"""The run picture: trace data structure, track thinning, JSON round trip and the PNG."""
from __future__ import annotations

import json
import math
import random

import pytest
from hypothesis import given, settings, strategies as st

from runtime import config as C
from runtime.errors import InputError
from sitl import run_plot
from sitl.run_trace import KEEP_DT, KEEP_MOVE, KEEP_TURN, RobotTrack, RunTrace, TaskMark

DT = 0.05          # 20 Hz
SPEED = 0.25       # m/s, the default cruise speed
TURN = 2.0         # rad/s

WORLD = C.WorldConfig(size=(10.0, 10.0), walls=True, obstacles=(
    C.Box(center=(-1.8, 0.3), size=(1.0, 1.0)),
    C.Box(center=(2.8, 0.8), size=(0.8, 0.8), yaw=0.785),
), source="configs/worlds/test.yaml")
TASKS = {1: ("goto", -3.5, 3.5), 2: ("goto", 3.5, 3.8), 3: ("goto", 3.8, -1.0), 4: ("goto", -3.5, -3.8),
         5: ("goto", -1.0, -2.5), 6: ("goto", 1.5, 1.2), 7: ("rendezvous", 0.0, 3.2)}
STARTS = {1: (-3.0, -4.2, math.pi / 2), 2: (-1.0, -4.2, math.pi / 2), 3: (1.0, -4.2, math.pi / 2),
          4: (3.0, -4.2, math.pi / 2)}
LOST = (4, 35.0)   # robot 4 dies on its way to task 5, which then goes to robot 3


def synthetic_trace() -> RunTrace:
    """4 robots drive (unicycle, 20 Hz) through 6 goto tasks and a 2-robot rendezvous; R2 fails task 6
    (re-awarded to R3), R4 is lost on its way to task 5 (withdrawn, re-awarded to R3)."""
    tr = RunTrace(world=WORLD, title="synthetic: 4 robots, 7 tasks, one lost")
    for tid, (kind, x, y) in TASKS.items():
        tr.tasks[tid] = TaskMark(tid, kind, x, y, label="RV" if kind == "rendezvous" else f"T{tid}",
                                 need=2 if kind == "rendezvous" else 1)
    pose = {rid: list(p) for rid, p in STARTS.items()}
    queue = {1: [1, 7], 2: [6, 2, 7], 3: [3], 4: [4, 5]}
    for rid in pose:
        tr.robots[rid] = RobotTrack(rid, base="create_oi", radius=0.17)
    tr.event(1.0, "armed", robots=list(pose))
    for rid, tasks in queue.items():
        for tid in tasks:
            tr.event(2.0, "awarded", tid, [rid], detail="auction")
    at_rv: set[int] = set()
    alive = set(pose)
    t = 0.0
    while t < 120.0 and any(queue[r] for r in alive):
        if abs(t - 8.0) < DT / 2:
            queue[2].remove(6)
            tr.event(t, "failed", 6, [2], detail="blocked")
            tr.event(t + 1.0, "awarded", 6, [3])
            queue[3].append(6)
        if abs(t - LOST[1]) < DT / 2:
            alive.discard(LOST[0])
            tr.robots[LOST[0]].lost_at = t
            tr.event(t, "lost", robots=[LOST[0]], detail="heartbeat timeout")
            tr.event(t, "withdrawn", 5, [LOST[0]])
            tr.event(t + 1.0, "awarded", 5, [3])
            queue[3].append(5)
        for rid in sorted(alive):
            x, y, yaw = pose[rid]
            tr.robots[rid].add(t, x, y, yaw)
            if t < 2.0 or not queue[rid] or rid in at_rv:
                continue
            tid = queue[rid][0]
            _, gx, gy = TASKS[tid]
            if math.hypot(gx - x, gy - y) < 0.08:
                tr.event(t, "arrived", tid, [rid])
                if tid == 7:
                    at_rv.add(rid)
                    if len(at_rv) == 2:
                        tr.event(t, "done", 7, sorted(at_rv))
                        tr.tasks[7].arrived_at = t
                        queue[1].clear(), queue[2].clear()
                    continue
                tr.event(t, "done", tid, [rid])
                tr.tasks[tid].arrived_at = t
                queue[rid].pop(0)
                continue
            err = math.remainder(math.atan2(gy - y, gx - x) - yaw, math.tau)
            yaw += max(-TURN * DT, min(TURN * DT, err))
            v = SPEED * max(0.0, math.cos(err))
            pose[rid] = [x + v * DT * math.cos(yaw), y + v * DT * math.sin(yaw), yaw]
        t = round(t + DT, 6)
    tr.event(t, "disarmed", robots=sorted(alive))
    return tr


@pytest.fixture(scope="module")
def trace() -> RunTrace:
    return synthetic_trace()


def test_synthetic_trace_is_what_it_claims(trace):
    assert len(trace.robots) == 4 and len(trace.tasks) == 7
    assert sum(tk.kind == "goto" for tk in trace.tasks.values()) == 6
    assert all(tk.arrived_at is not None for tk in trace.tasks.values()), "every task handed in"
    assert trace.robots[4].lost_at == LOST[1]
    assert {e.robots for e in trace.events if e.what == "done" and e.task == 5} == {(3,)}
    assert {e.robots for e in trace.events if e.what == "done" and e.task == 7} == {(1, 2)}


def test_timeline_bars(trace):
    bars = {(b.robot, b.task): b for b in run_plot.task_bars(trace)}
    assert bars[(2, 6)].how == "failed" and bars[(2, 6)].t1 == pytest.approx(8.0)
    assert bars[(4, 5)].how == "lost" and bars[(4, 5)].t1 == LOST[1]
    assert bars[(3, 5)].how == "done" and bars[(3, 5)].t0 == LOST[1] + 1.0
    assert bars[(1, 7)].how == "done" and bars[(1, 7)].t1 == trace.tasks[7].arrived_at
    # R2 held T6, T2 and RV at once from t = 2: three lanes, each bar its own
    r2 = [b for b in bars.values() if b.robot == 2]
    assert {b.lanes for b in r2} == {3} and len({b.lane for b in r2}) == 3


def test_lost_robot_still_holding_a_task_ends_its_bar_when_lost():
    tr = RunTrace()
    tr.robots[1] = RobotTrack(1)
    tr.robots[1].add(0.0, 0.0, 0.0, 0.0)
    tr.robots[1].add(50.0, 1.0, 0.0, 0.0)
    tr.robots[1].lost_at = 20.0
    tr.event(1.0, "awarded", 9, [1])
    (bar,) = run_plot.task_bars(tr)
    assert (bar.t0, bar.t1, bar.how) == (1.0, 20.0, "lost")


def test_task_outcome(trace):
    assert run_plot.task_outcome(trace, trace.tasks[7])[:2] == ("done", (1, 2))
    assert run_plot.task_outcome(RunTrace(), TaskMark(1, "goto", 0, 0)) == ("open", (), None)


def _pixels_near(img, rgb, tol=0.06) -> int:
    import numpy as np
    return int((np.abs(img[..., :3] - np.asarray(rgb[:3])).max(axis=-1) < tol).sum())


def test_png_of_the_synthetic_run(trace, tmp_path):
    from matplotlib.image import imread
    out = run_plot.plot_run(trace, tmp_path / "sub" / "run.png")
    assert out == tmp_path / "sub" / "run.png"
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert 30_000 < len(data) < 3_000_000
    img = imread(out)
    assert img.shape[0] > 600 and img.shape[1] > 1200
    # each robot's colour shows up (path, footprint, bars), and the lost cross (red) too
    for rid, col in run_plot.robot_colours(list(trace.robots)).items():
        assert _pixels_near(img, col) > 300, f"robot {rid} colour barely drawn"
    assert _pixels_near(img, (1.0, 0.0, 0.0)) > 50


def test_json_round_trip(trace, tmp_path):
    again = RunTrace.from_json(trace.to_json(), "x.json")
    assert again == trace
    assert again.world.source == WORLD.source
    assert again.to_json() == trace.to_json()
    assert RunTrace.read(trace.write(tmp_path / "trace.json")) == trace


def test_round_trip_detects_a_difference(trace):
    data = json.loads(trace.to_json())
    data["events"][3]["t"] += 0.5
    assert RunTrace.from_dict(data) != trace


def _straight_drive(track: RobotTrack, seconds: float, speed: float) -> list[tuple]:
    raw = []
    for k in range(int(seconds / DT) + 1):
        t = k * DT
        raw.append((t, -4.0 + speed * t, 1.0, 0.3))
        track.add(*raw[-1])
    return raw


# At 20 Hz the 2 cm rule keeps every 2nd sample at 0.25 m/s and every sample from 0.4 m/s up (a step is
# then >= 2 cm); parked, the 0.5 s rule keeps 2 a second.
@pytest.mark.parametrize("speed, kept_at_most", [(0.0, 0.101), (SPEED, 0.501), (0.5, 1.0)])
def test_thinning_one_hour_straight_drive(speed, kept_at_most):
    tr = RobotTrack(1)
    raw = _straight_drive(tr, 3600.0, speed)
    s = tr.samples
    assert s[0] == raw[0] and s[-1] == pytest.approx(raw[-1], abs=1e-4)
    bound = 3600.0 * speed / KEEP_MOVE + 3600.0 / KEEP_DT + 2
    assert len(s) <= bound and len(s) <= kept_at_most * len(raw), (len(s), len(raw))
    for a, b in zip(s, s[1:-1]):
        assert b[0] - a[0] <= KEEP_DT + DT + 1e-9        # never a longer gap than the time rule allows
        assert (math.hypot(b[1] - a[1], b[2] - a[2]) >= KEEP_MOVE - 1e-4 or b[0] - a[0] >= KEEP_DT - 1e-4)


def test_thinning_keeps_turns_in_place_and_the_newest_pose():
    tr = RobotTrack(1)
    for k in range(41):                       # 90 deg turn in place over 2 s
        tr.add(k * DT, 0.0, 0.0, math.radians(90.0 * k / 40))
    yaws = [s[3] for s in tr.samples]
    assert yaws[-1] == pytest.approx(math.pi / 2, abs=1e-4)
    assert all(b - a >= KEEP_TURN - 1e-4 for a, b in zip(yaws, yaws[1:-1]))
    assert 90 / (5 + 2.25) <= len(yaws) <= 90 / 5 + 2    # 2.25 deg a step
    tr.add(float("nan"), 0, 0, 0)
    assert tr.skipped == 1 and len(tr.samples) == len(yaws)


def test_pose_at():
    tr = RobotTrack(1)
    assert tr.pose_at(3.0) is None
    for k in range(5):
        tr.add(float(k), float(k), 0.0, 0.0)
    assert tr.pose_at(2.5)[1] == 2.0 and tr.pose_at(-1.0)[1] == 0.0 and tr.pose_at(99.0)[1] == 4.0


def test_event_kind_checked():
    with pytest.raises(ValueError):
        RunTrace().event(1.0, "exploded")


@pytest.mark.parametrize("with_robots", [False, True])
def test_no_events_no_tasks_still_plots(tmp_path, with_robots):
    tr = RunTrace(world=C.WorldConfig(size=(6.0, 4.0), walls=False))
    if with_robots:
        tr.robots[7] = RobotTrack(7, radius=0.2)
        tr.robots[7].add(0.0, -1.0, 0.0, 0.0)
        tr.robots[8] = RobotTrack(8)          # never sampled
    out = run_plot.plot_run(tr, tmp_path / "empty.png")
    assert out.stat().st_size > 5_000


def test_ten_robots_thirty_tasks_plot(tmp_path):
    rnd = random.Random(4)
    tr = RunTrace(title="10 robots, 30 tasks")
    for rid in range(1, 11):
        tr.robots[rid] = RobotTrack(rid)
        for k in range(60):
            tr.robots[rid].add(k * 1.0, rnd.uniform(-4, 4), rnd.uniform(-4, 4), 0.0)
    for tid in range(30):
        tr.tasks[tid] = TaskMark(tid, rnd.choice(["goto", "goto", "survey"]), rnd.uniform(-4, 4), rnd.uniform(-4, 4))
        rid = tid % 10 + 1
        tr.event(tid, "awarded", tid, [rid])
        tr.event(tid + 20, "done", tid, [rid])
        tr.tasks[tid].arrived_at = tid + 20.0
    out = run_plot.plot_run(tr, tmp_path / "big.png")
    assert out.stat().st_size > 30_000


# ---------------------------------------------------------------------- trace.json is a parser

def _valid_text() -> str:
    tr = RunTrace(world=WORLD, title="t")
    tr.robots[1] = RobotTrack(1)
    tr.robots[1].add(0.0, 1.0, 2.0, 0.1)
    tr.robots[1].add(1.0, 1.5, 2.0, 0.1)
    tr.tasks[3] = TaskMark(3, "goto", 1.0, 1.0, "T3", arrived_at=4.0)
    tr.event(0.5, "awarded", 3, [1])
    tr.event(4.0, "done", 3, [1], detail="ok")
    return tr.to_json()


VALID = _valid_text()


def _parse(text: str) -> None:
    try:
        RunTrace.from_json(text, "trace.json")
    except InputError as exc:
        assert "\n" not in str(exc) and str(exc).startswith("trace.json")


@settings(max_examples=300, deadline=None)
@given(st.integers(0, len(VALID)))
def test_truncated_trace_file(n):
    _parse(VALID[:n])


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.integers(0, len(VALID) - 1), st.integers(0, 7)), min_size=1, max_size=4))
def test_bit_flipped_trace_file(flips):
    b = bytearray(VALID.encode())
    for pos, bit in flips:
        b[pos] ^= 1 << bit
    _parse(b.decode("utf-8", errors="replace"))


json_values = st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5),
                           lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=5), inner,
                                                                                        max_size=3), max_leaves=8)


@settings(max_examples=300, deadline=None)
@given(st.data())
def test_random_values_anywhere_in_the_trace(data):
    doc = json.loads(VALID)
    node, key = doc, None
    while True:                     # walk to a random spot and put a random value there
        keys = list(node) if isinstance(node, dict) else list(range(len(node)))
        if not keys:
            break
        key = data.draw(st.sampled_from(keys))
        if not isinstance(node[key], (dict, list)) or data.draw(st.booleans()):
            break
        node = node[key]
    if key is not None:
        node[key] = data.draw(json_values)
    try:
        RunTrace.from_dict(doc, "trace.json")
    except InputError as exc:
        assert "\n" not in str(exc)


def test_bad_trace_names_the_key():
    doc = json.loads(VALID)
    doc["robots"][0]["samples"][1] = [1.0, 2.0]
    with pytest.raises(InputError, match=r"^trace.json: robots\[0\].samples\[1\]: expected \[t, x, y, yaw\]$"):
        RunTrace.from_dict(doc, "trace.json")


# ---------------------------------------------------------------------- command line

def test_cli_redraws(trace, tmp_path, capsys):
    path = trace.write(tmp_path / "run" / "trace.json")
    assert run_plot.main([str(path)]) == 0
    assert (tmp_path / "run" / "trace.png").stat().st_size > 30_000
    assert run_plot.main([str(path), str(tmp_path / "other.png")]) == 0
    assert (tmp_path / "other.png").is_file()


def test_cli_bad_file_is_one_line_exit_2(tmp_path, capsys):
    bad = tmp_path / "trace.json"
    bad.write_text("{\"format\": 1}")
    assert run_plot.main([str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("run_plot: ") and "format" in err
    assert run_plot.main([str(tmp_path / "missing.json")]) == 2
