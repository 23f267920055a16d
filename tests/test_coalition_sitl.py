"""Acceptance in the SITL (lock-step, deterministic): six Create 2 daemons allocate rendezvous tasks by the
coalition method (configs/fleets/coalition_6.yaml).  Coalitions meet around their points, round 1 is optimal
over the bids received, the leftover task is done after the first finish, and a member killed mid-drive has
its task offered again and done."""
from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from runtime.allocation.agent import DONE, RELEASED
from runtime.allocation.coalition import meeting
from sitl import launcher
from sitl.operator import RunView
from tests.sitl_util import shipped_fleet

ROOT = Path(__file__).resolve().parents[1]
FLEET = ROOT / "configs" / "fleets" / "coalition_6.yaml"
EKF_MARGIN = 0.15          # m: a daemon drives on its pose estimate (GPS noise 0.3 m), not on the true pose


def _fleet_copy(tmp_path) -> Path:
    return shipped_fleet(tmp_path, FLEET.name)


class Watch:
    """Samples the true poses after every control cycle: for each task, the closest its coalition came to being
    all together at the point (the largest member distance, minimised over time), and when tasks finished.
    With ``kill_at``, kills the highest-id robot (not the auctioneer) driving to its slot at that time: its
    daemon stops and is closed (motors stopped, socket shut)."""

    def __init__(self, kill_at: float | None = None):
        self.closest: dict[int, float] = {}
        self.coalition: dict[int, tuple[int, ...]] = {}
        self.done_at: dict[int, float] = {}
        self.kill_at = kill_at
        self.victim: tuple[int, int] | None = None       # (robot, task)

    def __call__(self, f, run) -> None:
        ds = {rid: d for rid, d in run.daemons.items() if rid not in run.stopped}
        jobs: dict[int, dict[int, tuple]] = {}
        for rid, d in ds.items():
            job = d.core.agent.member.job
            if job is not None:
                jobs.setdefault(job.task, {})[rid] = (job.round, job.robots)
            for ev in d.core.node.events:
                if ev.what == DONE and ev.task not in self.done_at:
                    self.done_at[ev.task] = f.world.t
        table = ds[min(ds)].core.node.table.entries
        for task, who in jobs.items():
            coalitions = set(who.values())
            assert len(coalitions) == 1, f"t={f.world.t:.2f}: task {task} held by two coalitions {who}"
            (_, robots), = coalitions
            if set(who) != set(robots):
                continue
            point = table[task].task.position
            spread = max(math.dist(f.true_pose(r)[:2], point) for r in robots)
            if spread < self.closest.get(task, math.inf):
                self.closest[task], self.coalition[task] = spread, robots
        if self.kill_at is not None and self.victim is None and f.world.t >= self.kill_at:
            for rid in sorted(ds, reverse=True):
                job = ds[rid].core.agent.member.job
                if rid != min(ds) and job is not None and not job.arrived:
                    self.victim = (rid, job.task)
                    run.kill(rid)
                    ds[rid].close()
                    return


def _run(tmp_path, watch: Watch, timeout: float = 150.0) -> tuple[dict, dict, float]:
    """Lock-step until every task is done: the run's result, the live robots' daemons, the goal tolerance."""
    f = launcher.build(_fleet_copy(tmp_path), tmp_path / "run", seed=1)
    run = launcher.Lockstep(f)
    try:
        goal = False
        while f.world.t < timeout and not goal:
            run.step()
            watch(f, run)
            goal = f.scenario.goal(RunView(run.op))
        res = launcher.finish(f, run.op, "goal" if goal else "timeout", picture=False)
        live = {rid: d for rid, d in run.daemons.items() if rid not in run.stopped}
    finally:
        run.close()
        f.close()
    return res, live, live[min(live)].cfg.control.goal_tolerance


def _ring(k: int, agent) -> float:
    return meeting.ring_radius(k, agent.estimator.profile.radius, agent.options.spacing)


@pytest.mark.slow
def test_coalitions_meet_leftover_after_the_first_finish_and_round_one_is_optimal(tmp_path):
    from tests.test_coalition_fleet import brute_force

    watch = Watch()
    res, daemons, tolerance = _run(tmp_path, watch)
    assert res["goal_met"] and res["valid"], res
    ids = [row["task"] for row in res["tasks"]]
    assert sorted(watch.done_at) == sorted(ids)
    auct = daemons[1].core.agent
    first = auct.rounds[0]
    assert first.robots == (1, 2, 3, 4, 5, 6) and first.tasks == tuple(sorted(ids))
    assert math.isclose(first.value, brute_force(first.tasks, first.bids))
    (late,) = set(ids) - set(first.winners)                          # 9 places, 6 robots: one left over
    first_finish = min(watch.done_at.values())
    assert next(r for r in auct.rounds if late in r.winners).opened >= first_finish
    assert watch.done_at[late] > first_finish
    needs = {(t["x"], t["y"]): t["robots"] for t in yaml.safe_load(FLEET.read_text())["scenario"]["tasks"]}
    for row in res["tasks"]:
        task, k = row["task"], len(watch.coalition[row["task"]])
        assert k == needs[(row["x"], row["y"])]
        limit = _ring(k, auct) + tolerance + EKF_MARGIN
        assert watch.closest[task] <= limit, (task, watch.closest[task], limit)
    print({f"{t >> 16}.{t & 0xFFFF}": (watch.coalition[t], round(watch.closest[t], 3), round(watch.done_at[t], 1))
           for t in ids}, "round 1 value", round(first.value, 3), "over", len(first.bids), "bids; sim",
          round(res["sim_time"], 1), "s")


@pytest.mark.slow
def test_a_member_killed_mid_drive_has_its_task_offered_again_and_done(tmp_path):
    watch = Watch(kill_at=8.0)
    res, daemons, _ = _run(tmp_path, watch)
    assert watch.victim is not None
    victim, task = watch.victim
    assert res["goal_met"] and res["valid"], res
    auctioneer = daemons[min(daemons)]
    auct = auctioneer.core.agent
    assert victim in auctioneer.core.stats.peers_lost                           # by heartbeat timeout
    assert any(ev.what == RELEASED and ev.task == task and f"robot {victim} lost" in ev.detail
               for ev in auctioneer.core.node.events)
    assert sum(1 for r in auct.rounds if task in r.winners) >= 2            # won again in a later round
    assert victim not in watch.coalition[task]
    print("killed", victim, "task", task, "done at", round(watch.done_at[task], 1), "by", watch.coalition[task])


def test_the_run_summary_prints_who_did_each_task_and_when():
    import io

    from sitl.scenarios.mission import Scenario
    rows = [{"label": "T0", "task": 65537, "x": -1.5, "y": 1.5, "at": 0.0, "to": 1, "state": "done", "by": (2, 3),
             "done_at": 21.04},
            {"label": "op", "task": 131073, "x": 0.0, "y": 0.0, "at": None, "to": 2, "state": "open", "by": (),
             "done_at": None}]
    out = io.StringIO()
    Scenario.print_summary({"tasks": rows, "driven": {1: 2.0}, "done": 1, "sim_time": 30.0}, out)
    lines = out.getvalue().splitlines()
    assert "R2+R3" in lines[2] and lines[2].rstrip().endswith("21.0") and "0.0 s" in lines[2]
    assert lines[3].split()[1] == "2.1" and lines[3].rstrip().endswith("-")
