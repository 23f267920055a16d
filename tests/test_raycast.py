"""The SITL's one ray-cast helper: beam sets mounted on bodies, several bodies in one batch, own-body hits."""
from __future__ import annotations

import math

import numpy as np
import pytest

from runtime import config as C

pytest.importorskip("pybullet")
from sitl.sensing import raycast  # noqa: E402
from sitl.world import World  # noqa: E402

HALF = 3.0


@pytest.fixture(scope="module")
def world():
    boxes = (C.Box(center=(-1.5, 1.5), size=(0.5, 0.5)), C.Box(center=(1.8, -1.2), size=(0.3, 0.8), yaw=0.4))
    with World(C.WorldConfig(size=(2 * HALF, 2 * HALF), obstacles=boxes), wheel_radius_sigma=0.0) as w:
        bots = [w.add_body(1, (0.5, 0.0, 0.3), "pioneer3dx"), w.add_body(2, (-1.0, -1.0, 2.0), "pioneer3dx"),
                w.add_body(3, (1.0, 1.5, -1.0), "create2")]
        w.step(40)
        yield w, bots


def test_a_batch_of_bodies_reads_bit_for_bit_what_each_reads_alone(world):
    _, bots = world
    angles = np.linspace(0, 2 * math.pi, 90, endpoint=False)
    sets = [b.sonar for b in bots[:2]]
    sets += [raycast.Beams(b, raycast.mounted(raycast.laser(angles), (0.1, 0.0, 0.5)), z, 12.0)
             for b in bots for z in (0.25, 0.12)]
    together, n = raycast.cast_many(sets)
    assert n >= sum(len(s.rays) for s in sets)
    for s, d in zip(sets, together):
        (alone,), _ = raycast.cast_many([s])
        assert np.array_equal(alone, d)
    assert all(np.all(d < 12.0) for d in together[2:])     # a closed arena: every laser beam hits something


def test_a_mounted_laser_reads_the_walls_where_its_pose_says(world):
    _, bots = world
    bot = bots[0]
    x, y, yaw = bot.pose()
    mount = (0.1, -0.05, math.pi / 2)                         # turned to face the robot's left
    beams = raycast.Beams(bot, raycast.mounted(raycast.laser(np.array([0.0])), mount), 0.28, 12.0)
    (d,), _ = raycast.cast_many([beams])
    ox = x + math.cos(yaw) * 0.1 + math.sin(yaw) * 0.05
    oy = y + math.sin(yaw) * 0.1 - math.cos(yaw) * 0.05
    a = yaw + math.pi / 2
    want = min((HALF - oy) / math.sin(a), (-HALF - ox) / math.cos(a))
    assert d[0] == pytest.approx(want, abs=1e-3)


def test_a_beam_through_its_own_body_is_cast_again_past_it(world):
    _, bots = world
    bot = bots[1]
    x, y, yaw = bot.pose()
    behind = raycast.mounted(raycast.laser(np.array([0.0])), (-0.40, 0.0, 0.0))    # 0.4 m behind, facing forward
    (d,), n = raycast.cast_many([raycast.Beams(bot, behind, 0.12, 12.0)])
    ox, oy = x - 0.40 * math.cos(yaw), y - 0.40 * math.sin(yaw)
    walls = min(t for t in ((HALF - ox) / math.cos(yaw) if math.cos(yaw) > 0 else math.inf,
                            (-HALF - ox) / math.cos(yaw) if math.cos(yaw) < 0 else math.inf,
                            (HALF - oy) / math.sin(yaw) if math.sin(yaw) > 0 else math.inf,
                            (-HALF - oy) / math.sin(yaw) if math.sin(yaw) < 0 else math.inf))
    assert n >= 2 and d[0] > 0.6 and d[0] <= walls + 1e-6      # through the hull, then the world beyond it


def test_select_and_along_keep_the_mount(world):
    _, bots = world
    ring = bots[0].sonar
    sub = ring.select([0, 7])
    assert set(sub.rays[:, 3]) == {0.0, 7.0} and len(sub.rays) == 10
    steps = raycast.Beams(bots[0], raycast.mounted(raycast.laser(np.zeros(1)), (0.2, 0.1, 0.0)), 0.25, 12.0)
    more = steps.along(np.array([0.0, 1.0, 2.0]))
    assert np.array_equal(more.rays[:, 0], [0.2] * 3) and np.array_equal(more.rays[:, 2], [0.0, 1.0, 2.0])
