"""`mrta experiment formation-ideal|formation-twobox|formation-world` (paper 002) on reduced grids:
files and columns, paper numbers beside ours, what the methods must satisfy, and the drive mode."""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from runtime import cli
from runtime.allocation.formation.assignment import hungarian, straight_line_costs
from runtime.errors import InputError
from runtime.planning.grid import OccupancyGrid, random_obstacle_world, rasterise_boxes
from sitl.experiments import formation_common as fc
from sitl.experiments import formation_world as fw

SWEEP_COLUMNS = {"distribution", "robots", "method", "cases", "mean_error_pct", "max_error_pct", "min_error_pct",
                 "optimal_cases", "mean_messages", "mean_rounds", "not_converged", "cpu_s", "same_as_closed_form"}


def _rows(path):
    return list(csv.DictReader(path.open()))


def test_ideal_reduced_run(tmp_path, capsys):
    out = tmp_path / "ideal"
    assert cli.main(["experiment", "formation-ideal", "--out", str(out), "--cases", "5", "--max-robots", "6",
                     "--repeats", "4"]) == 0
    assert "closed form n=6: 4 samples of 5 cases" in capsys.readouterr().err      # progress without -v
    rows = _rows(out / "formation_ideal.csv")
    # the agents end in the deferred-acceptance matching on every instance
    assert all(r["same_as_closed_form"] == "5" for r in rows if r["method"] in ("bs", "rtma"))
    expected = _rows(out / "formation_ideal_expected.csv")
    assert sorted((int(r["robots"]), r["method"]) for r in expected) == [
        (n, m) for n in range(2, 7) for m in ("bs", "rtma")]
    for r in expected:
        assert r["samples"] == "4" and r["cases_per_sample"] == "5"
        assert float(r["max_p5_pct"]) <= float(r["expected_max_pct"]) <= float(r["max_p95_pct"])

    assert set(rows[0]) == SWEEP_COLUMNS
    assert sorted({(int(r["robots"]), r["method"]) for r in rows}) == [
        (n, m) for n in range(2, 7) for m in sorted(fc.METHODS)]
    assert all(r["not_converged"] == "0" and r["cases"] == "5" for r in rows)
    mean = {m: np.mean([float(r["mean_error_pct"]) for r in rows if r["method"] == m]) for m in fc.METHODS}
    assert mean["rtma"] <= mean["bs"]
    assert mean["bs"] > 0                                   # BS is not optimal on these instances
    # the auction ends within n * eps_final of the optimum (1 ppm of the largest cost): exact here
    assert max(float(r["max_error_pct"]) for r in rows if r["method"] == "auction") == 0.0
    rtma2 = next(r for r in rows if r["method"] == "rtma" and r["robots"] == "2")
    assert rtma2["max_error_pct"] == "0.0" and rtma2["optimal_cases"] == "5"
    md = (out / "formation_ideal.md").read_text()
    assert "## Fig. 6 and 7: error vs robots" in md and "| robots | BS mean % | BS max % | BS msgs |" in md
    assert "RTMA always optimal with 2 robots | 0 % in every case | 5/5 optimal" in md
    assert (out / "formation_ideal.png").stat().st_size > 10_000


def test_auction_is_within_n_eps_of_the_optimum():
    rng = np.random.default_rng(5)
    for n in (2, 5, 9):
        robots, tasks = fc.uniform_instance(rng, n)
        c = straight_line_costs(robots, tasks)
        opt = hungarian(c)[1]
        res = fc.run_methods(c, ("auction", "bs"), opt)
        eps_final = 1e-6 * c.max() / (n + 1)          # simulate's cost_unit for real costs, over n + 1
        assert res["auction"]["converged"] and res["auction"]["cost"] <= opt + n * eps_final + 1e-9
        assert res["bs"]["cost"] >= opt - 1e-9
        assert sorted(res["auction"]["assignment"]) == list(range(n))


def test_twobox_reduced_run(tmp_path):
    out = tmp_path / "twobox"
    assert cli.main(["experiment", "formation-twobox", "--out", str(out), "--cases", "5", "--max-robots", "5",
                     "--methods", "bs,rtma", "--repeats", "3", "--sensitivity-cases", "4"]) == 0
    rows = _rows(out / "formation_twobox.csv")
    assert set(rows[0]) == SWEEP_COLUMNS
    assert {(r["distribution"], r["method"]) for r in rows} == {
        ("twobox", "bs"), ("twobox", "rtma"), ("uniform", "bs"), ("uniform", "rtma")}
    md = (out / "formation_twobox.md").read_text()
    for heading in ("Two-box distribution (our reconstruction)", "Fig. 9: error vs robots, two-box (agents)",
                    "Two-box vs uniform, mean error (agents, same run)",
                    "Two-box vs uniform, expected mean error (closed form)",
                    "Paper's statements (Section IV-A, Fig. 9) beside ours: expected, 3 x 5 cases per size"):
        assert f"## {heading}" in md
    assert "400 m small box and a 700 m big box" in md
    # one sensitivity line per (small, big) box pair, each with a verdict
    sens = [line for line in md.splitlines() if line.startswith("| ") and line.count("|") == 9
            and line.split("|")[1].strip().replace(".", "").isdigit()]
    assert len(sens) == 15 and all(line.rstrip(" |").split("|")[-1].strip() in ("yes", "no") for line in sens)
    expected = _rows(out / "formation_twobox_expected.csv")
    assert {(r["distribution"], r["method"]) for r in expected} == {
        ("twobox", "bs"), ("twobox", "rtma"), ("uniform", "bs"), ("uniform", "rtma")}
    assert (out / "formation_twobox.png").stat().st_size > 10_000
    assert (out / "formation_twobox_instance.png").stat().st_size > 5_000


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 40), inside=st.floats(0.51, 1.0), seed=st.integers(0, 2**32 - 1),
       small=st.floats(10, 400), extra=st.floats(1, 500))
def test_twobox_points_follow_the_reconstruction(n, inside, seed, small, extra):
    big = min(small + extra, 990.0)
    pts = fc.box_points(np.random.default_rng(seed), n, 1000.0, small, big, inside)
    assert pts.shape == (n, 2)
    d = np.max(np.abs(pts - 500.0), axis=1)
    k = fc.inside_count(n, inside)
    assert np.all(d[:k] <= small / 2) and np.all(d[k:] > big / 2) and np.all((pts >= 0) & (pts <= 1000))
    assert k > n / 2 or n == 2                           # "most" in the small box
    assert k < n or n == 1 or inside == 1.0              # and some outside the big one


def test_world_costs_reduced_run(tmp_path):
    out = tmp_path / "world"
    assert cli.main(["experiment", "formation-world", "--out", str(out), "--cases", "2", "--robots", "4",
                     "--fractions", "20"]) == 0
    rows = _rows(out / "formation_world.csv")
    assert {"planner", "robots", "obstacles_pct", "method", "cases", "mean_global_cost", "mean_error_pct",
            "max_error_pct", "mean_messages", "not_converged", "skipped_unreachable"} == set(rows[0])
    get = {(r["planner"], r["method"]): r for r in rows}
    assert set(get) == {(p, m) for p in ("astar", "rrt") for m in ("bs", "rtma", "auction", "hungarian")}
    opt = float(get[("astar", "hungarian")]["mean_global_cost"])
    for (p, m), r in get.items():
        assert r["not_converged"] == "0" and r["skipped_unreachable"] == "0"
        assert float(r["mean_global_cost"]) >= opt - 1e-6           # nothing beats the A* optimum
        assert float(r["mean_error_pct"]) >= -1e-9
    assert float(get[("astar", "auction")]["max_error_pct"]) == 0.0
    assert float(get[("rrt", "hungarian")]["mean_global_cost"]) <= float(get[("rrt", "bs")]["mean_global_cost"]) + 1e-6
    md = (out / "formation_world.md").read_text()
    assert "## Table I: A* bid costs" in md and "## Table II: RRT bid costs" in md
    assert "(127.38)" in md and "(155.49)" in md and "(117.19)" in md      # paper's cells beside ours
    assert (out / "formation_world.png").stat().st_size > 10_000
    assert not (out / "formation_world_drive.csv").exists()


@pytest.mark.parametrize("size, res, pct", [(75.0, 0.5, 40), (20.0, 0.25, 20), (33.0, 0.3, 5)])
def test_boxes_snapped_to_cells_mark_the_same_cells(size, res, pct):
    raw = random_obstacle_world(size, res, pct / 100, seed=1000 + pct)
    world, grid = fw.scenario(size, res, pct, seed=1)
    empty = OccupancyGrid.empty(world.size, res)
    assert len(world.obstacles) == len(raw.obstacles)
    assert np.array_equal(rasterise_boxes(empty, raw.obstacles), rasterise_boxes(empty, world.obstacles))
    x0, y0 = empty.origin
    for box in world.obstacles:           # every edge on a cell edge
        for c, h, o in ((box.center[0], box.size[0] / 2, x0), (box.center[1], box.size[1] / 2, y0)):
            for edge in (c - h, c + h):
                assert abs((edge - o) / res - round((edge - o) / res)) < 1e-6


def test_missions_are_reproducible_spaced_and_clear_of_boxes():
    world, grid = fw.scenario(30.0, 0.5, 20, seed=3)
    assert 0.19 <= np.mean(grid.occ) <= 0.5
    a = fw.mission(world, 5, 1, 20, 0)
    b = fw.mission(world, 5, 1, 20, 0)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    robots, yaws, tasks = a
    for pts in (robots, tasks):
        gap = np.hypot(*(pts[:, None, :] - pts[None, :, :]).transpose(2, 0, 1))
        assert np.all(gap[np.triu_indices(5, 1)] >= fw.SPACING)
    for x, y in np.vstack([robots, tasks]):
        assert grid.is_free(x, y)
        for box in world.obstacles:        # the body fits: no box edge within the robot radius
            dx = max(abs(x - box.center[0]) - box.size[0] / 2, 0.0)
            dy = max(abs(y - box.center[1]) - box.size[1] / 2, 0.0)
            assert math.hypot(dx, dy) > 0.17
    assert not np.array_equal(fw.mission(world, 5, 1, 20, 1)[0], robots)
    c = fw.planner_costs(grid, robots, tasks, "rrt", seed=0, iterations=3000)
    assert np.all(np.isfinite(c)) and np.all(c >= straight_line_costs(robots, tasks) - 1e-9)


def test_drive_summary_pools_every_mission_of_a_planner():
    """The "all" row of each planner is the mean over its missions, not a mean of cell means: a cell with
    more missions weighs more. An invalid mission is left out of every mean."""
    from sitl.experiments import formation_world as fw

    def row(n, pct, case, method, driven, valid=True):
        return {"planner": "astar", "robots": n, "obstacles_pct": pct, "case": case, "method": method,
                "driven_m": driven, "planned_cost": 100.0, "optimum_astar": 100.0, "arrived": n, "valid": valid}
    rows = [row(4, 5, 0, "bs", 110.0), row(4, 5, 0, "rtma", 100.0),
            row(4, 5, 1, "bs", 130.0), row(4, 5, 1, "rtma", 90.0),
            row(6, 5, 0, "bs", 150.0), row(6, 5, 0, "rtma", 200.0, valid=False)]
    lines = fw.drive_summary(rows, ("bs", "rtma")).splitlines()
    every = [ln for ln in lines if ln.startswith("| A* all |")]
    assert len(every) == 1
    cells = [c.strip() for c in every[0].strip("|").split("|")]
    # planner, robots, obstacles, missions, BS driven, BS planned err, BS driven err, RTMA driven, ...
    assert cells[1:4] == ["all", "all", "3"]
    assert float(cells[4]) == pytest.approx(130.0)                   # (110 + 130 + 150) / 3, not (120 + 150) / 2
    assert cells[6] == "30.00 %" and cells[9] == "-5.00 %"          # RTMA: the invalid 200 m mission left out
    assert cells[-1] == "22/22"                                       # robots over the 5 valid runs
    assert [ln for ln in lines if ln.startswith("| A* | 6 | 5 % | 1 |")]


@pytest.mark.slow
def test_world_drive_one_mission(tmp_path, monkeypatch, capsys):
    """One mission driven by daemons in the pybullet SITL on a scaled field: the daemons reach an assignment,
    every robot arrives, and the simulator's driven distance is close to the planned path length."""
    monkeypatch.chdir(tmp_path)                 # a relative --out, as `mrta experiment` defaults to
    out = tmp_path / "drive"
    assert cli.main(["experiment", "formation-world", "--out", "drive", "--cases", "1", "--robots", "2,4",
                     "--fractions", "5", "--planners", "astar", "--methods", "rtma", "--drive", "--drive-cases", "1",
                     "--drive-size", "20", "--drive-resolution", "0.25", "--no-png", "--jobs", "2"]) == 0
    two, r = _rows(out / "formation_world_drive.csv")        # two cells driven in parallel, kept in order
    assert two["robots"] == "2" and two["valid"] == "True" and two["arrived"] == "2"
    assert r["valid"] == "True" and r["arrived"] == "4" and r["method"] == "rtma" and r["field_m"] == "20.0"
    planned, driven = float(r["planned_cost"]), float(r["driven_m"])
    assert planned >= float(r["optimum_astar"]) - 1e-6
    assert 0.85 < driven / planned < 1.3
    assert float(r["sim_s"]) > planned / 4 / 0.5              # nobody drives faster than the cruise speed
    md = (out / "formation_world.md").read_text()
    assert "## Driven in the pybullet SITL (--drive)" in md and "scaled to 20 m" in md
    summary = [line for line in md.splitlines() if line.startswith("| A* | 4 | 5 % | 1 |")]
    assert len(summary) == 1 and summary[0].endswith("| 4/4 |")        # Tables I-II from the driven missions

    # --drive-resume: the earlier mission is kept as it was, only the new case is driven
    from sitl.experiments import formation_world as fw
    calls = []
    real = fw.drive_mission
    monkeypatch.setattr(fw, "drive_mission", lambda *a, **k: calls.append(a) or real(*a, **k))
    base = ["experiment", "formation-world", "--cases", "1", "--robots", "2", "--fractions", "5", "--planners",
            "astar", "--methods", "rtma", "--drive", "--drive-size", "20", "--drive-resolution", "0.25", "--no-png",
            "--jobs", "1", "--drive-resume", "drive/formation_world_drive.csv"]
    assert cli.main(base + ["--out", "more", "--drive-cases", "2"]) == 0
    assert len(calls) == 1 and "case1" in str(calls[0][1])
    kept, new = _rows(tmp_path / "more" / "formation_world_drive.csv")
    assert kept == two and new["case"] == "1" and new["valid"] == "True"
    assert "--drive-resume drive/formation_world_drive.csv" in (tmp_path / "more" / "formation_world.md").read_text()
    capsys.readouterr()
    assert cli.main(base + ["--out", "other", "--cruise-speed", "0.4"]) == 2     # driven at another speed
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cruise_speed = 0.5, expected 0.4" in err[0]


@pytest.mark.parametrize("name, argv, needle", [
    ("formation-ideal", ["--cases", "0"], "--cases 0"),
    ("formation-ideal", ["--max-robots", "1"], "--max-robots 1"),
    ("formation-ideal", ["--methods", "bs,greedy"], "--methods 'bs,greedy'"),
    ("formation-twobox", ["--inside", "0.3"], "--inside 0.3"),
    ("formation-twobox", ["--small-box", "800"], "--small-box 800 --big-box 700"),
    ("formation-twobox", ["--sensitivity-cases", "-1"], "--sensitivity-cases -1"),
    ("formation-ideal", ["--repeats", "0"], "--repeats 0"),
    ("formation-world", ["--robots", "4,x"], "--robots '4,x'"),
    ("formation-world", ["--planners", "dijkstra"], "--planners 'dijkstra'"),
    ("formation-world", ["--fractions", "90"], "--fractions '90'"),
    ("formation-world", ["--cruise-speed", "2"], "--cruise-speed 2"),
    ("formation-world", ["--jobs", "0"], "--jobs 0"),
])
def test_bad_arguments_exit_2_with_one_line(tmp_path, capsys, name, argv, needle):
    assert cli.main(["experiment", name, "--out", str(tmp_path)] + argv) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=30))
def test_list_parsers_return_or_raise_input_error(text):
    for call in (lambda: fc.parse_ints(text, "--robots", 2, 250),
                 lambda: fc.parse_names(text, "--planners", ("astar", "rrt"))):
        try:
            out = call()
        except InputError as exc:
            assert "\n" not in str(exc) and "--" in str(exc)
        else:
            assert out and all(isinstance(v, (int, str)) for v in out)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.integers(-5, 300), min_size=1, max_size=6), st.data())
def test_list_parser_on_truncated_lists(values, data):
    text = ",".join(map(str, values))
    cut = data.draw(st.integers(0, len(text)))
    part = text[:cut]
    try:
        out = fc.parse_ints(part, "--robots", 2, 250)
    except InputError:
        return
    assert list(out) == [int(x) for x in part.split(",")] and all(2 <= v <= 250 for v in out)


@given(st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10, 10)))
def test_positive_accepts_only_finite_positive(value):
    try:
        v = fc.positive(value, "--size", 1000.0)
    except InputError as exc:
        assert not (math.isfinite(value) and 0 < value <= 1000) and "--size" in str(exc)
    else:
        assert 0 < v <= 1000


def test_mission_timeout_covers_the_longest_path_of_either_planner():
    from sitl.experiments.formation_world import mission_timeout
    a_star = np.array([[10.0, 20.0], [15.0, 12.0]])
    rrt = np.array([[14.0, 60.0], [np.inf, 13.0]])          # a detour, and a pair RRT did not connect
    assert mission_timeout(a_star, a_star, 0.5) == pytest.approx(30 + 2 * 20 / 0.5)
    assert mission_timeout(a_star, rrt, 0.5) == pytest.approx(30 + 2 * 60 / 0.5)


_DRIVE_HEADER = ("planner,robots,obstacles_pct,method,case,field_m,resolution_m,seed,cruise_speed,inflate_m,"
                 "rrt_iterations,rrt_raw,drive_timeout,driven_m,arrived,valid\n")
_DRIVE_ROW = "astar,4,5,rtma,0,75.0,0.5,1,0.5,0.42,20000,False,nan,101.5,4,True\n"


@settings(max_examples=150, deadline=None)
@given(body=st.text(max_size=200) | st.builds(lambda k: (_DRIVE_HEADER + _DRIVE_ROW)[:k], st.integers(0, 200)),
       raw=st.binary(max_size=60))
def test_drive_resume_file_never_raises_anything_but_input_error(tmp_path_factory, body, raw):
    """Random, truncated and undecodable --drive-resume files: rows or one InputError, nothing else."""
    import argparse
    from runtime.errors import InputError
    from sitl.experiments.formation_world import load_resume
    args = argparse.Namespace(drive_size=None, size=75.0, drive_resolution=None, resolution=0.5, seed=1,
                              cruise_speed=0.5, drive_inflate=0.42, rrt_iterations=20000, rrt_raw=False,
                              drive_timeout=None)
    d = tmp_path_factory.mktemp("resume")
    for name, data in (("text.csv", body.encode()), ("bytes.csv", raw)):
        path = d / name
        path.write_bytes(data)
        try:
            load_resume(path, args)
        except InputError:
            pass
    assert load_resume(_write(d / "ok.csv", _DRIVE_HEADER + _DRIVE_ROW), args)[("astar", 4, 5, 0, "rtma")]["valid"]


def _write(path, text):
    path.write_text(text)
    return path


def _stand_in_mission(fleet_path, run_dir, method, timeout) -> dict:
    """What :func:`formation_world.drive_mission` returns, for two robots, without driving: the bookkeeping
    tests below need rows, not a pybullet run (test_world_drive_one_mission drives them)."""
    return {"assignment": {1: 0, 2: 1}, "valid": True, "bid_cost": 1.0, "driven": 2.0,
            "driven_per_robot": {1: 1.0, 2: 1.0}, "arrived": 2, "sim_time": 10.0, "wall_s": 0.5,
            "events": [f"stand-in for {Path(run_dir).name}"]}


def test_interrupted_drive_keeps_finished_missions_for_resume(tmp_path, monkeypatch):
    """Each driven mission is saved when it finishes: after a crash in the second mission, the first is on disk
    and --drive-resume drives only what is missing."""
    from sitl.experiments import formation_world as fw
    monkeypatch.chdir(tmp_path)
    real_mission = _stand_in_mission
    missions = []

    def crashing_mission(*a, **k):
        missions.append(a)
        if len(missions) == 2:
            raise RuntimeError("power cut")
        return real_mission(*a, **k)

    argv = ["experiment", "formation-world", "--out", "run", "--cases", "1", "--robots", "2", "--fractions", "5",
            "--planners", "astar", "--methods", "rtma", "--drive", "--drive-cases", "2", "--drive-size", "20",
            "--drive-resolution", "0.25", "--no-png", "--jobs", "1"]          # one cell of two missions
    monkeypatch.setattr(fw, "drive_mission", crashing_mission)
    with pytest.raises(RuntimeError, match="power cut"):
        cli.main(argv)
    saved = _rows(tmp_path / "run" / "formation_world_drive.csv")
    assert [r["case"] for r in saved] == ["0"]
    missions.clear()
    monkeypatch.setattr(fw, "drive_mission", lambda *a, **k: missions.append(a) or real_mission(*a, **k))
    (tmp_path / "run" / "formation_world_drive.csv").rename(tmp_path / "first.csv")
    assert cli.main(argv + ["--drive-resume", "first.csv", "first.csv"]) == 0       # several files: merged
    assert len(missions) == 1 and "case1" in str(missions[0][1])
    both = _rows(tmp_path / "run" / "formation_world_drive.csv")
    assert [r["case"] for r in both] == ["0", "1"] and both[0] == saved[0]
    missions.clear()                   # everything resumed, nothing driven: the report still has its CSV
    assert cli.main(argv[:3] + ["again"] + argv[4:] + ["--drive-resume", "run/formation_world_drive.csv"]) == 0
    assert not missions and _rows(tmp_path / "again" / "formation_world_drive.csv") == both
