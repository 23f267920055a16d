"""Shipped fleets under a lossy network, lock-step (deterministic per seed): three runs that failed before the
fixes they prove.

* can_2, 10 % loss, seed 2: the loss crossed the two CAN bases' paths, they collided, and robot 1, turned by pi
  with its wheels not seeing it, drove the wrong way on a confident heading for 100 s (past the 90 s limit).
  The pose filter now relocalises (runtime/localization/ekf.py).  The formation rounds no longer cross the paths
  at this loss (docs/formation.md), so the test turns robot 1 by pi itself, on its way, as the collision did.
* create2_4, 10 % loss in 2 s spells, seed 1: a spell kept robot 1's round start from robot 4, which started a
  round of its own and split the problem: the diamond ended 23.9 % above the optimum.  A free robot now holds off
  while a lower robot may have a round it never heard of (runtime/allocation/formation/family.py).
* coalition_6, 10 % loss in 2 s spells, seed 1: a robot released from the three-robot rendezvous stayed parked on
  a meeting slot and the member sent there waited behind it until the 150 s limit.  An idle robot without range
  sensors now makes way by its peers' reported positions (runtime/execution/peer_readings.py).
"""
from __future__ import annotations

import math

import pytest

from tests.sitl_util import lockstep_run, shipped_fleet


def _run(tmp_path, name: str, seed: int, on_step=None, **changes):
    def read(f):                                             # what --stats files show, per robot
        snaps = {rid: r.daemon.snapshot() for rid, r in f.robots.items()}
        return {rid: (s["relocalised"], s["made_way"]) for rid, s in snaps.items()}

    return lockstep_run(shipped_fleet(tmp_path, name, seed=seed, **changes), tmp_path / "run", read, on_step)


class Knock:
    """Turn robot ``rid``'s body by pi where it stands, once, at ``at`` s: its wheels do not see it."""

    def __init__(self, rid: int, at: float):
        self.rid, self.at, self.done = rid, at, False

    def __call__(self, f) -> None:
        if not self.done and f.world.t >= self.at:
            body = f.robots[self.rid].body
            x, y, yaw = body.pose()
            body.place(x, y, yaw + math.pi)
            self.done = True


@pytest.mark.slow
def test_can_2_at_a_tenth_loss_relocalises_the_robot_turned_in_a_collision_and_meets_its_goal(tmp_path):
    knock = Knock(1, 6.0)
    res, counts = _run(tmp_path, "can_2.yaml", 2, on_step=knock, peer_loss=0.1)
    assert knock.done and res["goal_met"], res["verdict"]
    assert counts[1][0] >= 1, counts
    print(f"goal at {res['sim_time']:.1f} s (limit 90 s); relocalised {counts}")


@pytest.mark.slow
def test_coalition_6_in_loss_spells_clears_a_meeting_slot_and_meets_its_goal(tmp_path):
    res, counts = _run(tmp_path, "coalition_6.yaml", 1, peer_loss=0.1, loss_burst=2.0)
    assert res["goal_met"], res["verdict"]
    assert any(made > 0 for _, made in counts.values()), counts
    print(f"goal at {res['sim_time']:.1f} s (limit 150 s); cycles spent making way {counts}")


@pytest.mark.slow
def test_create2_4_in_loss_spells_takes_up_the_optimal_formation(tmp_path):
    res, _ = _run(tmp_path, "create2_4.yaml", 1, peer_loss=0.1, loss_burst=2.0)
    assert res["goal_met"], res["verdict"]
    assert res["global_cost"] <= res["optimum"] * (1 + 1e-6), (res["global_cost"], res["optimum"])   # was +23.9 %
    print(f"goal at {res['sim_time']:.1f} s; global cost {res['global_cost']:.3f} m, optimum {res['optimum']:.3f} m")
