"""The pybullet SITL world and its simulated Create 2 bodies: kinematics, contacts, determinism."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from runtime.config import Box, WorldConfig, load_world
from runtime.errors import InputError
from sitl.bodies import create2 as M
from sitl.bodies.create2 import SimCreate2
from sitl.world import World

ROOT = Path(__file__).resolve().parents[1]
WORLD_FILES = sorted((ROOT / "configs" / "worlds").glob("*.yaml"))
ARENA = WorldConfig(size=(10.0, 10.0))


@pytest.fixture
def world():
    w = World(ARENA, seed=3, wheel_radius_sigma=0.0)
    yield w
    w.close()


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def _step_until_bump(w: World, bot: SimCreate2, limit_s: float) -> tuple[bool, bool]:
    for _ in range(int(limit_s / w.dt)):
        w.step()
        if any(bot.bumps()):
            return bot.bumps()
    pytest.fail(f"no bump within {limit_s} s, pose {bot.pose()}")


# ------------------------------------------------------------------ kinematics

def test_straight_at_commanded_speed_and_wheel_travel_matches_ground_truth(world):
    bot = world.add_body(1, (-2.0, 1.0, 0.5), "create2")
    bot.set_wheel_speeds(0.2, 0.2)
    world.step(100)                      # settle the acceleration
    x0, y0, yaw0 = bot.pose()
    l0, r0 = bot.wheel_travel()
    t0 = world.t
    world.step(600)
    x1, y1, yaw1 = bot.pose()
    l1, r1 = bot.wheel_travel()
    dist = math.hypot(x1 - x0, y1 - y0)
    speed = dist / (world.t - t0)
    assert speed == pytest.approx(0.2, rel=0.03)
    assert (l1 - l0) == pytest.approx(dist, rel=0.02)
    assert (r1 - r0) == pytest.approx(dist, rel=0.02)
    assert math.atan2(y1 - y0, x1 - x0) == pytest.approx(0.5, abs=0.01)    # along the heading (ENU)
    assert abs(_wrap(yaw1 - yaw0)) < 0.01
    vx, vy = bot.velocity()
    assert (vx, vy) == pytest.approx((0.2 * math.cos(0.5), 0.2 * math.sin(0.5)), abs=0.006)


def test_reverse_wheel_travel_is_negative(world):
    bot = world.add_body(1, (0.0, 0.0, 0.0), "create2")
    bot.set_wheel_speeds(-0.1, -0.1)
    world.step(400)
    left, right = bot.wheel_travel()
    x, _, _ = bot.pose()
    assert x < -0.15
    assert left == pytest.approx(x, rel=0.02) and right == pytest.approx(x, rel=0.02)


def test_spin_in_place_at_the_rate_the_track_predicts(world):
    bot = world.add_body(1, (1.0, -1.0, 0.0), "create2")
    v = 0.15
    bot.set_wheel_speeds(-v, v)
    world.step(100)
    x0, y0, yaw0 = bot.pose()
    t0, turned, prev = world.t, 0.0, yaw0
    for _ in range(400):
        world.step()
        yaw = bot.pose()[2]
        turned += _wrap(yaw - prev)
        prev = yaw
    rate = turned / (world.t - t0)
    assert rate == pytest.approx(2 * v / M.WHEEL_TRACK, rel=0.05)
    assert bot.yaw_rate() == pytest.approx(2 * v / M.WHEEL_TRACK, rel=0.05)
    x1, y1, _ = bot.pose()
    assert math.hypot(x1 - x0, y1 - y0) < 0.01          # turns about its own centre


def test_wheel_speed_is_clipped_to_half_a_metre_per_second(world):
    bot = world.add_body(1, (-3.0, 0.0, 0.0), "create2")
    bot.set_wheel_speeds(2.0, 9.0)
    assert bot.wheel_targets() == (0.5, 0.5)
    world.step(100)
    x0 = bot.pose()[0]
    world.step(200)
    assert (bot.pose()[0] - x0) / 1.0 == pytest.approx(0.5, rel=0.03)


# ------------------------------------------------------------------ contacts

def test_driving_into_a_wall_bumps_both_and_stops(world):
    bot = world.add_body(1, (4.0, 0.0, 0.0), "create2")
    bot.set_wheel_speeds(0.3, 0.3)
    assert bot.bumps() == (False, False)
    assert _step_until_bump(world, bot, 5.0) == (True, True)
    world.step(100)
    x0 = bot.pose()[0]
    world.step(400)                                     # keeps pushing for 2 s
    assert bot.bumps() == (True, True)
    assert abs(bot.pose()[0] - x0) < 0.002
    assert bot.pose()[0] == pytest.approx(5.0 - M.SHELL_RADIUS, abs=0.005)


@pytest.mark.parametrize("yaw,expected", [(math.radians(35), (False, True)), (math.radians(-35), (True, False)),
                                          (math.radians(5), (True, True))])
def test_bump_side_follows_the_angle_of_approach(world, yaw, expected):
    # The east wall is at x = +5; heading +35 deg it lies 35 deg to the right of the heading.
    bot = world.add_body(1, (4.2, 0.0, yaw), "create2")
    bot.set_wheel_speeds(0.2, 0.2)
    assert _step_until_bump(world, bot, 5.0) == expected


def test_rear_contact_is_not_a_bump(world):
    front = world.add_body(1, (0.0, 0.0, 0.0), "create2")
    back = world.add_body(2, (-1.0, 0.0, 0.0), "create2")
    back.set_wheel_speeds(0.3, 0.3)
    front.set_wheel_speeds(0.1, 0.1)
    assert _step_until_bump(world, back, 6.0) == (True, True)
    assert front.bumps() == (False, False)


def test_robot_pushes_a_slower_robot_through_contact(world):
    front = world.add_body(1, (0.0, 0.0, 0.0), "create2")
    back = world.add_body(2, (-0.6, 0.0, 0.0), "create2")
    front.set_wheel_speeds(0.1, 0.1)
    back.set_wheel_speeds(0.3, 0.3)
    world.step(800)                                      # contact after ~1.3 s
    gap = math.dist(front.pose()[:2], back.pose()[:2])
    assert gap == pytest.approx(2 * M.SHELL_RADIUS, abs=0.005)
    assert front.velocity()[0] > 0.15                   # faster than its own 0.1 m/s: pushed
    assert back.bumps() == (True, True)


def test_head_on_robots_both_bump_and_stop(world):
    a = world.add_body(1, (-1.0, 0.0, 0.0), "create2")
    b = world.add_body(2, (1.0, 0.0, math.pi), "create2")
    a.set_wheel_speeds(0.2, 0.2)
    b.set_wheel_speeds(0.2, 0.2)
    world.step(1200)
    assert a.bumps() == (True, True) and b.bumps() == (True, True)
    pa, pb = a.pose()[:2], b.pose()[:2]
    world.step(200)
    assert math.dist(pa, a.pose()[:2]) < 0.002 and math.dist(pb, b.pose()[:2]) < 0.002
    assert math.dist(pa, pb) == pytest.approx(2 * M.SHELL_RADIUS, abs=0.005)


def test_box_obstacle_stops_the_robot():
    w = World(WorldConfig(size=(10.0, 10.0), obstacles=(Box(center=(2.0, 0.0), size=(1.0, 1.0), height=0.3,
                                                             yaw=0.0),)))
    try:
        bot = w.add_body(1, (0.0, 0.0, 0.0), "create2")
        bot.set_wheel_speeds(0.4, 0.4)
        assert _step_until_bump(w, bot, 6.0) == (True, True)
        w.step(400)
        assert bot.pose()[0] == pytest.approx(1.5 - M.SHELL_RADIUS, abs=0.005)
    finally:
        w.close()


def test_wheel_drop_only_when_lifted(world):
    bot = world.add_body(1, (0.0, 0.0, 0.0), "create2")
    world.step(20)
    assert bot.wheel_drop() == (False, False)
    bot.place(0.0, 0.0, 0.0, z=0.5)
    world.step()
    assert bot.wheel_drop() == (True, True)
    world.step(400)                                     # falls back onto its wheels
    assert bot.wheel_drop() == (False, False)
    assert bot.height() == pytest.approx(M.SHELL_CENTRE_Z, abs=0.003)


def _per_link(bot: SimCreate2, link: int) -> list:
    return sorted(cp[5] for cp in M.p.getContactPoints(bodyA=bot.body_id, linkIndexA=link, physicsClientId=bot._client)
                  if cp[2] != bot.body_id and cp[8] <= M.CONTACT_MARGIN)


def test_contacts_are_fetched_once_per_step_and_match_per_link_queries(world, monkeypatch):
    """Bumpers and wheel drop share one contact query per physics step.  Each step, the shared list
    split by link equals what pybullet answers when asked per link (shell and both wheels), through a
    drive into the wall, a lift and a fall."""
    bot = world.add_body(1, (4.0, 0.0, math.radians(20)), "create2")
    bot.set_wheel_speeds(0.3, 0.3)
    calls = {"n": 0}
    real = M.p.getContactPoints

    def counting(*a, **k):
        calls["n"] += 1
        return real(*a, **k)

    seen_bump = seen_drop = False
    for i in range(1200):
        if i == 900:
            bot.place(4.0, 0.0, 0.0, z=0.3)
        world.step()
        monkeypatch.setattr(M.p, "getContactPoints", counting)
        before = calls["n"]
        for _ in range(3):                       # the device asks several times per step
            seen_bump |= any(bot.bumps())
            seen_drop |= any(bot.wheel_drop())
        assert calls["n"] - before == 1
        monkeypatch.setattr(M.p, "getContactPoints", real)
        for link in (-1, M.LEFT, M.RIGHT):
            assert sorted(cp[5] for cp in bot.contacts() if cp[3] == link) == _per_link(bot, link)
    assert seen_bump and seen_drop


# ------------------------------------------------------------------ battery

def test_battery_discharges_and_a_stall_draws_more_than_cruising(world):
    bot = world.add_body(1, (3.0, 0.0, 0.0), "create2")
    b0 = bot.battery()
    assert b0["capacity_mah"] == 2696
    assert 0 < b0["charge_mah"] <= b0["capacity_mah"]
    world.step(10)
    idle = bot.battery()["current_ma"]
    bot.set_wheel_speeds(0.3, 0.3)
    world.step(200)
    cruise = bot.battery()["current_ma"]
    world.step(1400)                                    # at the wall, motors at their torque limit
    assert bot.bumps() == (True, True)
    stall = bot.battery()
    assert stall["current_ma"] < cruise < idle < 0
    assert stall["charge_mah"] < b0["charge_mah"]
    assert stall["voltage_mv"] < bot.battery()["voltage_mv"] + 1e-9
    assert 10 < stall["temperature_c"] < 60


# ------------------------------------------------------------------ determinism, configs, errors

def _scripted_run(seed: int, steps: int = 1500) -> list[tuple[float, ...]]:
    """Four robots on crossing courses with seeded command changes; returns every robot's state."""
    w = World(load_world(ROOT / "configs" / "worlds" / "boxes_10m.yaml"), seed=seed)
    try:
        starts = [(-1.5, -1.5, 0.78), (1.5, 1.5, -2.36), (-1.5, 1.5, -0.78), (1.5, -1.5, 2.36)]
        bots = [w.add_body(i + 1, s, "create2") for i, s in enumerate(starts)]
        rng = np.random.default_rng(seed)
        for k in range(steps // 100):
            for b in bots:
                b.set_wheel_speeds(*rng.uniform(-0.1, 0.5, size=2))
            w.step(100)
        return [b.pose() + b.velocity() + b.wheel_travel() + (b.battery()["charge_mah"],) for b in bots]
    finally:
        w.close()


def test_same_seed_same_commands_identical_states():
    first, second = _scripted_run(11), _scripted_run(11)
    assert first == second                              # exact, not approximate
    assert _scripted_run(12) != first


def test_worlds_in_one_process_are_independent():
    a, b = World(ARENA, seed=1), World(ARENA, seed=1)
    try:
        ra, rb = a.add_body(1, (0.0, 0.0, 0.0), "create2"), b.add_body(1, (0.0, 0.0, 0.0), "create2")
        ra.set_wheel_speeds(0.3, 0.3)
        a.step(200)
        b.step(200)
        assert ra.pose()[0] > 0.2 and abs(rb.pose()[0]) < 1e-3
        assert a.t == b.t == pytest.approx(1.0)
        assert set(a.bodies) == {1} and a.bodies[1] is ra
    finally:
        a.close()
        b.close()


@pytest.mark.parametrize("path", WORLD_FILES, ids=lambda p: p.name)
def test_every_world_config_loads_and_builds(path):
    cfg = load_world(path)
    w = World(cfg, seed=1)
    try:
        assert len(w.obstacle_ids) == len(cfg.obstacles)
        assert len(w.wall_ids) == (4 if cfg.walls else 0)
        bot = w.add_body(1, (cfg.size[0] / 2 - 0.5, cfg.size[1] / 2 - 0.5, 0.0), "create2")
        w.step(50)
        assert bot.wheel_drop() == (False, False) and bot.bumps() == (False, False)
    finally:
        w.close()


def test_shipped_world_configs_exist():
    names = {p.name for p in WORLD_FILES}
    assert {"arena_10m.yaml", "boxes_10m.yaml"} <= names


def test_bad_inputs_raise_one_line_input_errors(world):
    world.add_body(4, (0.0, 0.0, 0.0), "create2")
    cases = [lambda: world.add_body(4, (1.0, 1.0, 0.0), "create2"),
             lambda: world.add_body(5, (4.95, 0.0, 0.0), "create2"),
             lambda: world.add_body(6, (0.0, float("nan"), 0.0), "create2"),
             lambda: world.bodies[4].set_wheel_speeds(float("inf"), 0.0),
             lambda: World(ARENA, dt=0.0)]
    for case in cases:
        with pytest.raises(InputError) as info:
            case()
        assert "\n" not in str(info.value) and ("robot" in str(info.value) or "dt" in str(info.value))


def test_an_unknown_body_kind_names_the_known_ones(world):
    with pytest.raises(InputError, match=r"body kind 'tank': expected one of create2"):
        world.add_body(1, (0.0, 0.0, 0.0), "tank")
    assert world.bodies == {}


def test_the_body_radius_is_the_drivers_and_the_planners():
    from runtime.drivers.create_oi import create_footprint
    from runtime.planning.grid import CREATE2_RADIUS
    assert SimCreate2.radius == M.SHELL_RADIUS == CREATE2_RADIUS == create_footprint("create2").radius
    assert M.WHEEL_TRACK == create_footprint("create2").track


def test_close_is_idempotent():
    w = World(ARENA, wheel_radius_sigma=0.0)
    w.close()
    w.close()


def test_body_has_create2_dimensions_and_mass(world):
    import pybullet as p
    bot = world.add_body(1, (0.0, 0.0, 0.0), "create2")
    kw = {"physicsClientId": world.client_id}
    mass = sum(p.getDynamicsInfo(bot.body_id, link, **kw)[0] for link in range(-1, p.getNumJoints(bot.body_id, **kw)))
    assert mass == pytest.approx(3.6, abs=0.01)
    lo, hi = p.getAABB(bot.body_id, -1, **kw)
    assert hi[0] - lo[0] == pytest.approx(0.34, abs=0.01) and hi[1] - lo[1] == pytest.approx(0.34, abs=0.01)
    assert hi[2] == pytest.approx(0.092, abs=0.005)
    wheels = [p.getJointInfo(bot.body_id, j, **kw) for j in (M.LEFT, M.RIGHT)]
    assert all(info[2] == p.JOINT_REVOLUTE for info in wheels)
    assert wheels[0][14][1] - wheels[1][14][1] == pytest.approx(0.235)      # track from the joint frames
    assert p.getCollisionShapeData(bot.body_id, M.LEFT, **kw)[0][3][0] == pytest.approx(0.036)


@pytest.fixture(scope="module")
def shared():
    w = World(ARENA, seed=5, wheel_radius_sigma=0.0)
    bot = w.add_body(1, (0.0, 0.0, 0.0), "create2")
    yield w, bot
    w.close()


@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(st.floats(allow_nan=False, allow_infinity=False, width=32),
       st.floats(allow_nan=False, allow_infinity=False, width=32))
def test_any_finite_wheel_command_is_clipped_and_the_body_stays_upright(shared, left, right):
    w, bot = shared
    bot.place(0.0, 0.0, 0.0)
    bot.set_wheel_speeds(left, right)
    tl, tr = bot.wheel_targets()
    assert tl == max(-0.5, min(0.5, left)) and tr == max(-0.5, min(0.5, right))
    l0, r0 = bot.wheel_travel()
    w.step(40)
    l1, r1 = bot.wheel_travel()
    assert abs(l1 - l0) <= 0.5 * 0.2 + 1e-3 and abs(r1 - r0) <= 0.5 * 0.2 + 1e-3
    assert bot.height() == pytest.approx(M.SHELL_CENTRE_Z, abs=0.01)
    assert bot.wheel_drop() == (False, False)


def test_tyre_tolerance_makes_encoder_odometry_drift():
    """With real tyre spread the encoders (nominal radius) disagree with the ground truth distance
    by each wheel's radius error: odometry error comes from the physics, not a formula."""
    w = World(ARENA, seed=11, wheel_radius_sigma=0.004)
    try:
        r = w.add_body(1, (0.0, 0.0, 0.0), "create2")
        assert r.wheel_radii[0] != r.wheel_radii[1]
        r.set_wheel_speeds(0.2, 0.2)
        w.step(1000)
        left, right = r.wheel_travel()
        x, y, _ = r.pose()
        true_dist = math.hypot(x, y)
        mean_scale = (r.wheel_radii[0] + r.wheel_radii[1]) / (2 * 0.036)
        assert abs((left + right) / 2 * mean_scale - true_dist) < 0.01 * true_dist
    finally:
        w.close()
