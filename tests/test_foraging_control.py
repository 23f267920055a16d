"""The arbiter's time to collision, as the foraging sweeps run it fast, against a brute-force oracle that tests
every sampled position of every arc against every range point (what the arbiter computed before it was made
fast): the same first-hit times, arc by arc, on random scans."""
from __future__ import annotations

import math

import numpy as np
import pytest

from runtime.control.arbiter import ArcSet
from runtime.control.behaviours import AvoidObstacles


def brute_force(avoid: AvoidObstacles, arcs: ArcSet, horizon: float, steps: int) -> np.ndarray:
    out = np.full(len(arcs.v), np.inf)
    pts = avoid._points
    if len(pts) == 0:
        return out
    clearance = avoid.radius + avoid.margin
    t = np.linspace(horizon / steps, horizon, steps)
    v, w = arcs.v[:, None], arcs.w[:, None]
    small = np.abs(w) < 1e-9
    safe_w = np.where(small, 1.0, w)
    x = np.where(small, v * t, v / safe_w * np.sin(w * t))
    y = np.where(small, 0.0, v / safe_w * (1 - np.cos(w * t)))
    for k in range(len(arcs.v)):
        for s in range(steps):
            d2 = (x[k, s] - pts[:, 0]) ** 2 + (y[k, s] - pts[:, 1]) ** 2
            d0 = pts[:, 0] ** 2 + pts[:, 1] ** 2
            if np.any((d2 <= clearance ** 2) & (d2 < d0 - 1e-12)):
                out[k] = t[s]
                break
    return out


@pytest.mark.parametrize("arcs", [ArcSet.uniform(max_speed=0.25, max_turn_rate=2.0),
                                  ArcSet.uniform(max_speed=0.5, max_reverse=0.2, max_turn_rate=2.0, n_speeds=11),
                                  ArcSet((-0.1, 0.0, 0.07, 0.3), (-1.0, -0.1, 0.0, 0.5, 3.0)),    # uneven axes
                                  ArcSet.uniform(max_speed=0.5, max_reverse=0.2, n_speeds=100, n_turns=3)],
                         ids=["pioneer", "create", "uneven", "more-speeds-than-a-word"])
def test_time_to_collision_equals_the_brute_force_oracle(arcs):
    rng = np.random.default_rng(7)
    for trial in range(25):
        n = int(rng.integers(1, 17))
        near = trial % 2 == 0                 # a crowd: points just outside the clearance, or anywhere in reach
        dist = rng.uniform(0.28, 0.5, n) if near else rng.uniform(0.0, 1.6, n)
        avoid = AvoidObstacles(radius=0.25)
        avoid.on_ranges(list(zip(rng.uniform(-math.pi, math.pi, n), dist)), now=0.0)
        for horizon, steps in ((3.0, 24), (2.0, 16)):
            fast = avoid.time_to_collision(arcs, horizon, steps)
            assert np.array_equal(fast, brute_force(avoid, arcs, horizon, steps)), (trial, horizon)


def test_a_point_dead_ahead_is_hit_by_forward_arcs_only_and_soonest_by_the_fastest():
    arcs = ArcSet.uniform(max_speed=0.25, max_turn_rate=2.0)
    avoid = AvoidObstacles(radius=0.25)
    avoid.on_ranges([(0.0, 0.81)], now=0.0)
    ttc = avoid.time_to_collision(arcs, 3.0, 24).reshape(arcs.shape)
    straight = arcs.turn_rates.index(0.0)
    col = ttc[:, straight]
    speeds = np.asarray(arcs.speeds)
    assert np.all(np.isinf(col[speeds <= 0]))                 # standing, turning or backing away: no hit
    assert col[-1] == pytest.approx(2.125)      # 0.51 m to close at 0.25 m/s: 2.04 s, sampled every 0.125 s
    hits = col[np.isfinite(col)]
    assert len(hits) >= 3 and np.all(np.diff(hits) < 0)        # faster hits sooner; the slowest not within 3 s
