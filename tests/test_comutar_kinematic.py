"""The kinematic fleet the CoMutaR reproduction runs on: real agents on the bus, discs that never overlap,
surveillance completed and agreed on, sensor sharing between a robot without a sensor and one with a laser;
and the experiment's command on a tiny sweep."""
from __future__ import annotations

import argparse
import math

import numpy as np
import pytest

from runtime.tasks.avoid_obstacles import AvoidObstacles
from sitl.experiments.comutar_kinematic import PIONEER_RADIUS, KinematicFleet
from runtime.tasks.surveillance import Surveillance
from runtime.errors import InputError
from runtime.tasks import Task
from sitl.experiments import comutar_surveillance as X


def _min_gap(fleet) -> float:
    p = fleet.poses[:, :2]
    d = np.hypot(p[:, None, 0] - p[None, :, 0], p[:, None, 1] - p[None, :, 1]) + np.eye(len(p)) * 1e9
    return float(d.min()) - 2 * PIONEER_RADIUS


def test_a_move_into_another_robot_slides_along_it_and_discs_never_overlap():
    fleet = KinematicFleet({1: (0.0, 0.0, 0.0), 2: (0.6, 0.1, math.pi)})
    want = fleet.poses.copy()
    want[0, :2] = (0.3, 0.0)                     # into robot 2 (centres 0.5 apart at contact)
    fleet._move(want)
    assert _min_gap(fleet) >= -1e-9 and fleet.contacts == 1
    assert fleet.poses[0, 1] < 0.0 and fleet.poses[0, 0] > 0.0   # pushed out along the normal: it slid down and on


def test_a_head_on_contact_keeps_right_instead_of_pushing_forever():
    fleet = KinematicFleet({1: (0.0, 0.0, 0.0), 2: (0.5, 0.0, math.pi)})   # touching, exactly in line
    want = fleet.poses.copy()
    want[0, :2] = (0.05, 0.0)
    fleet._move(want)
    assert _min_gap(fleet) >= -1e-9 and fleet.contacts == 1
    assert fleet.poses[0, 1] < -0.01                                      # it stepped to its right
    wedged = KinematicFleet({1: (0.0, 0.0, 0.0), 2: (0.5, 0.0, math.pi), 3: (0.0, -0.5, 0.0)})   # right blocked
    want = wedged.poses.copy()
    want[0, :2] = (0.05, 0.0)
    wedged._move(want)
    assert _min_gap(wedged) >= -1e-9 and wedged.poses[0, 1] > 0.01          # so it stepped to its left


def test_a_waiting_robot_parked_by_an_open_waypoint_stands_aside_so_its_claimant_can_reach_it():
    """Robot 2 waits beside the last open waypoint, claimed by robot 1 behind it: without standing aside,
    robot 1 could never come within the visit radius (discs cannot overlap)."""
    task = Task(1 << 16 | 1, "surveillance", Surveillance(0.0, 0.0, 2.0, 0.0, 2.0))    # (-1, 0) and (1, 0)
    fleet = KinematicFleet({1: (-3.0, 0.0, 0.0), 2: (1.2, 0.1, math.pi)})
    fleet.visits[task.id] = {}
    fleet.hand_in([task])
    board2 = fleet.agents[2].boards[task.id]
    board2.visit(0)                                 # robot 2 already saw (-1, 0) visited ...
    board2.claims[1] = (1, -1.0)                    # ... and robot 1 claimed (1, 0) long ago
    fleet.agents[1].boards[task.id].visit(0)
    fleet.visits[task.id][0] = (0.0, 1)
    fleet.agents[1].boards[task.id].target, fleet.agents[1].boards[task.id].claimed_at = 1, -1.0
    fleet.run(120.0, stop=lambda f: f.covered(task.id))
    assert fleet.covered(task.id) and fleet.visits[task.id][1][1] == 1
    assert board2.clear_of((1.2, 0.1), 0.6) is not None and board2.clear_of((3.0, 0.0), 0.6) is None


def test_a_crowded_start_makes_contacts_but_never_an_overlap():
    rng = np.random.default_rng(1)
    fleet = KinematicFleet(X.starts("B", 8, rng))
    task = Task(1 << 16 | 1, "surveillance", X.REGION)
    fleet.hand_in([task])
    gaps = []
    fleet.run(60.0, stop=lambda f: gaps.append(_min_gap(f)) and False)
    assert min(gaps) >= -1e-6 and fleet.contacts > 0


def test_a_surveillance_task_is_covered_and_every_agent_agrees_it_is_done():
    fleet = KinematicFleet({1: (-3.0, -3.0, 0.0), 2: (3.0, 3.0, math.pi), 3: (3.0, -3.0, math.pi / 2)})
    task = Task(2 << 16 | 1, "surveillance", Surveillance(0.0, 0.0, 4.0, 4.0, 2.0))
    fleet.hand_in([task])
    fleet.run(300.0, stop=lambda f: f.covered(task.id))
    assert fleet.covered(task.id) and len(fleet.visits[task.id]) == 9
    assert {r for _, r in fleet.visits[task.id].values()} == {1, 2, 3}          # all three took part
    fleet.run(fleet.now + 3.0)
    assert all(task.id not in a.bidder.holdings for a in fleet.agents.values())  # released after CmDone
    assert any(e.what == "done" for e in fleet.agents[2].events)
    assert fleet.revisits == 0 and fleet.conflicts == 0


def test_sensor_sharing_robot_one_surveys_among_obstacles_with_robot_twos_laser():
    res = X.sharing_run(seed=3)
    assert res["finished"] and res["waypoints"] == res["of"]
    assert res["contacts"] == 0 and res["min_clearance_m"] > 0.0
    assert res["roles"][(1, "avoid_obstacles")] == "obstacle_avoider"
    assert res["roles"][(2, "avoid_obstacles")].endswith("laser_reader")
    assert res["roles"][(1, "surveillance")] == "survey"
    assert res["links"][1] > 0 and res["links"][2] > 0                 # the obstacle list costs both links
    assert res["in_view"] > 0.5


@pytest.mark.parametrize("scenario", X.SCENARIOS)
def test_scenario_starts_never_overlap(scenario):
    rng = np.random.default_rng(0)
    pts = np.array([p[:2] for p in X.starts(scenario, 16, rng).values()])
    d = np.hypot(pts[:, None, 0] - pts[None, :, 0], pts[:, None, 1] - pts[None, :, 1]) + np.eye(16) * 1e9
    assert d.min() >= 2 * PIONEER_RADIUS
    if scenario == "B":
        assert (pts[:, 0] > 8).all() and (pts[:, 1] < -8).all()          # off the bottom-right corner


def test_performance_is_t1_over_n_tn_and_the_trend_checks_read_it():
    rows = []
    for s, times in (("A", {1: 100, 2: 55, 4: 30, 8: 16, 16: 8.5}), ("B", {1: 100, 2: 60, 4: 40, 8: 30, 16: 28}),
                     ("C", {1: 100, 2: 52, 4: 27, 8: 14, 16: 7.5})):
        for n, t in times.items():
            rows.append({"scenario": s, "robots": n, "finished": True, "time_s": t, "contacts": 0, "messages": 1})
    summary = X.summarise(rows)
    perf = {(r["scenario"], r["robots"]): r["performance"] for r in summary}
    assert perf[("A", 1)] == 1.0 and perf[("B", 16)] == pytest.approx(100 / (16 * 28))
    verdict = {c[0].split(":")[0]: c[3] for c in X.trends(summary)}
    assert verdict == {"scenario A": True, "scenario B": True, "scenario C": True,
                       "B below A and C at 16 robots (implied by Fig. 4b": True}


def test_bad_arguments_are_one_line_input_errors():
    with pytest.raises(InputError, match="--robots"):
        X.parse_counts("1-x")
    with pytest.raises(InputError, match="--scenarios"):
        X.parse_scenarios("A,D")
    assert X.parse_counts("1-4") == [1, 2, 3, 4] and X.parse_counts("8,2,2") == [2, 8]


def test_the_experiment_writes_its_csv_markdown_and_figures(tmp_path):
    parser = argparse.ArgumentParser()
    X.add_arguments(parser)
    args = parser.parse_args(["--runs", "1", "--robots", "1,2,4", "--scenarios", "A", "--jobs", "1", "--no-sharing"])
    args.out = str(tmp_path)
    assert X.run(args) == 0
    csv = (tmp_path / "comutar_surveillance.csv").read_text().splitlines()
    assert len(csv) == 4 and csv[0].startswith("scenario,robots,run")
    md = (tmp_path / "comutar_surveillance.md").read_text()
    assert "leans to stabilize" in md and "T(1) / (n T(n))" in md
    assert (tmp_path / "comutar_surveillance_performance.png").stat().st_size > 1000
