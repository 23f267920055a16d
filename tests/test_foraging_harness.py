"""The foraging harness end to end with a stand-in agent (tests/foraging_standin.py): objects handed in as
mission items and replaced as the fleet reports them done, weight conserved, utilities, a killed robot leaving
the run, loss on the bus, determinism for a seed, the calibration mode."""
from __future__ import annotations

import dataclasses
import math

import pytest

from runtime.allocation.agent import Method
from runtime.errors import InputError
from runtime.inprocess import FixedAgent
from sitl.foraging import scenario
from sitl.foraging.harness import ForagingConfig, ForagingRun, run
from sitl.foraging.scenario import Dist
from tests.foraging_standin import STANDIN, StandInOptions

# What is tested here is the harness, so the robots avoid each other by their bumpers only (sonar=False): with
# the sonar the executive cannot settle two robots meeting head-on (tests/test_foraging_deadlock.py), and a robot
# left without work parks where its last trip ended, on the delivery point (docs/foraging.md).  Hence also one
# robot per object and no more robots than objects.
BASE = ForagingConfig(robots=3, method=STANDIN, options=StandInOptions(cap=1), seed=3, time_limit=900.0, max_objects=5,
                      weight=Dist.const(4.0), deadline=Dist.uniform(40.0, 80.0), u_max=Dist.integers(50, 150),
                      size=8.0, sonar=False)


@pytest.fixture(scope="module")
def result():
    return run(BASE)


def test_objects_are_replaced_as_they_are_done_and_weight_is_conserved(result):
    objs = result.objects
    done = result.finished
    assert len(done) == BASE.max_objects, [(o.task, o.finished, o.delivered) for o in objs]
    assert len(objs) == BASE.max_objects                      # no more than asked for appeared
    assert [o.appeared for o in objs[:3]] == [0.0, 0.0, 0.0]  # three at once from the start
    finishes = sorted(o.finished for o in done)
    for o in objs[3:]:                                        # each later one appeared as one was done
        assert any(abs(o.appeared - f) < 1e-9 for f in finishes)
    for o in done:
        assert o.delivered == o.weight and o.pile == 0.0      # all of it reached D, nothing more
        assert math.hypot(o.x, o.y) >= BASE.min_distance
        assert max(abs(o.x), abs(o.y)) <= BASE.size / 2 - BASE.wall_margin
    loaded = sum(r.trips - r.empty_loads for r in result.robots.values())
    moved = sum(r.delivered for r in result.robots.values())
    assert moved == result.moved == sum(o.delivered for o in objs)
    assert loaded == pytest.approx(moved / 2.0)                # every trip that found weight carried a full 2 wu


def test_utilities_follow_eq_10_and_the_hard_deadline(result):
    for o in result.finished:
        e = o.finished - o.appeared
        dl = o.deadline
        soft = o.u_max if e < dl else o.u_max * 0.07 * dl / ((e - dl) + 0.07 * dl)
        assert o.utility_soft == pytest.approx(soft)
        assert o.utility_hard == (o.u_max if e < dl else 0.0)
    assert result.utility() == pytest.approx(sum(o.utility_soft for o in result.finished))
    assert result.utility(hard=True) == pytest.approx(sum(o.utility_hard for o in result.finished))


def test_eq_10_values():
    u = scenario.utility_soft
    assert u(50.0, 100.0, 80.0) == 80.0
    assert u(107.0, 100.0, 80.0) == pytest.approx(40.0)              # half at 1.07 DL
    assert u(150.0, 100.0, 1.0) == pytest.approx(0.123, abs=1e-3)     # digest: 1.5 DL -> 0.123
    assert u(200.0, 100.0, 1.0) == pytest.approx(0.065, abs=1e-3)
    assert scenario.utility_hard(100.0, 100.0, 80.0) == 0.0
    assert scenario.work_capacity(1.40, 2.0, 0.25, 0.12) == pytest.approx(0.02055 / 0.12, rel=1e-3)   # eq. 5 table


def test_coalitions_are_recorded(result):
    for o in result.finished:
        assert o.coalition[0] == (o.appeared, 0) and o.coalition[-1] == (o.finished, 0)
        assert max(n for _, n in o.coalition) >= 1
        assert 0 < o.mean_coalition(result.end) <= BASE.robots
    assert all(r.distance > 1.0 for r in result.robots.values())


def test_the_same_seed_gives_the_same_run(result):
    again = run(BASE)
    assert [(o.x, o.y, o.weight, o.appeared, o.finished, o.delivered) for o in again.objects] == \
           [(o.x, o.y, o.weight, o.appeared, o.finished, o.delivered) for o in result.objects]
    assert again.robots == result.robots


def test_a_killed_robot_leaves_the_run():
    cfg = dataclasses.replace(BASE, kills=((30.0, 2),), max_objects=4)
    fr = ForagingRun(cfg)
    try:
        trips_then = {}

        def observe(r):
            if abs(r.now - 30.0) < 1e-6:
                trips_then.update({k: v.trips for k, v in r.records.items()})
        res = fr.run(observe)
        assert res.robots[2].killed_at == pytest.approx(30.0)
        assert res.robots[2].trips == trips_then[2]                     # no trip after its death
        assert 2 not in fr.live() and 2 in fr.bus.down
        assert fr.world.pose(2)[0] > 100                                # its body left the arena
        for r in (1, 3):                                                # the others heard it go silent
            assert 2 in fr.robots[r].liveness.lost and 2 in fr.robots[r].node.agent.lost
        assert len(res.finished) == 4 and all(o.delivered == o.weight for o in res.finished)
        assert all(2 not in o.done_by for o in res.finished if o.finished > 30.0 + cfg.heartbeat_timeout + 1)
    finally:
        fr.close()


def test_lossy_bus_still_finishes_the_objects():
    res = run(dataclasses.replace(BASE, drop=0.2, max_objects=3, seed=4))
    assert res.messages.dropped > 0
    assert len(res.finished) == 3 and all(o.delivered == o.weight for o in res.finished)


def test_calibration_mode_moves_weight_without_agents():
    fr = ForagingRun(ForagingConfig(robots=2, method=None, time_limit=120.0, fixed_object=(1.4, 0.0), seed=1))
    try:
        res = fr.run()
    finally:
        fr.close()
    (obj,) = res.objects
    assert obj.delivered == res.moved > 0 and obj.finished is None and res.messages.sent == 0
    for h in fr.robots.values():          # nothing allocated: each robot kept the one commitment it was given
        assert isinstance(h.agent, FixedAgent) and [c.task_id for c in h.agent.commitments] == [obj.task]
        assert h.node.events == []


def test_a_method_that_does_not_allocate_transport_is_refused():
    other = Method(name="gotos", summary="", options=StandInOptions, make=STANDIN.make, task_kinds=("goto",))
    with pytest.raises(InputError, match="allocation method gotos: expected one that allocates transport tasks"):
        ForagingRun(dataclasses.replace(BASE, method=other))


def test_coalitions_of_two_share_an_object_and_conserve_its_weight():
    res = run(dataclasses.replace(BASE, robots=4, options=StandInOptions(cap=2), weight=Dist.const(8.0),
                                  max_objects=3, objects=2))
    assert len(res.finished) == 3 and all(o.delivered == o.weight for o in res.finished)
    lasting = [n for o in res.finished for (t, n), (t2, _) in zip(o.coalition, o.coalition[1:]) if t2 - t > 1.0]
    assert max(lasting) == 2                  # more only for a tick, while robots that chose together sort it out
    assert any(len(o.done_by) == 2 for o in res.finished)


def test_objects_appear_beyond_min_distance_and_min_angle_apart_seen_from_d():
    import numpy as np
    rng = np.random.default_rng(4)
    others = [(3.0, 0.0), (0.0, 3.0)]
    for _ in range(200):
        x, y = scenario.object_place(rng, 10.0, (0.0, 0.0), 2.0, 0.5, others, 90.0)
        assert math.hypot(x, y) >= 2.0 and max(abs(x), abs(y)) <= 4.5
        b = math.degrees(math.atan2(y, x))
        assert all(abs((b - o + 180) % 360 - 180) >= 90 for o in (0.0, 90.0))
    # no point is 90 degrees from both of two opposite objects but on a line: the draw missing it least is taken
    x, y = scenario.object_place(np.random.default_rng(1), 10.0, (0.0, 0.0), 2.0, 0.5, [(3.0, 0.0), (-3.0, 0.0)], 95.0)
    assert abs(math.degrees(math.atan2(abs(y), abs(x))) - 90) < 10
    run_ = ForagingRun(dataclasses.replace(BASE, robots=3, min_angle=90.0, max_objects=None, time_limit=0.2))
    try:
        bearings = [math.degrees(math.atan2(o.y, o.x)) for o in run_.objects.values()]
    finally:
        run_.close()
    assert len(bearings) == 3 and all(abs((a - b + 180) % 360 - 180) >= 90
                                      for i, a in enumerate(bearings) for b in bearings[i + 1:])
