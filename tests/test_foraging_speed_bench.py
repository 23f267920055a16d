"""benchmarks/foraging_speed.py's call clocks: what they time is inside what the harness times, and the run leaves
pybullet and FleetNode as they were."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pybullet as p

from runtime.fleet.node import FleetNode
from sitl.foraging.harness import ForagingConfig

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "foraging_speed.py"


def _bench():
    spec = importlib.util.spec_from_file_location("foraging_speed", BENCH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_floor_is_timed_inside_the_physics_and_the_agents_and_nothing_stays_wrapped():
    bench = _bench()
    before = {n: getattr(p, n) for n in bench.ENGINE_CALLS}, {n: getattr(FleetNode, n) for n in bench.NODE_CALLS}
    method, options = bench.method_of("dr")
    cfg = ForagingConfig(robots=4, method=method, options=options, seed=1, time_limit=4.0)
    plain = bench.measure(cfg)
    assert plain[0]["engine"] == plain[0]["node"] == 0.0           # the headline run times no call
    timing, wall, cpu, res = bench.measure(cfg, calls=True)
    assert bench.same_result(res, plain[3])
    assert 0 < timing["engine"] <= timing["physics"], timing
    assert 0 < timing["node"] <= timing["agents"], timing
    assert res.messages.sent > 0
    after = {n: getattr(p, n) for n in bench.ENGINE_CALLS}, {n: getattr(FleetNode, n) for n in bench.NODE_CALLS}
    assert after == before
    assert "engine" not in bench.split(timing) and "node" not in bench.split(timing)


def test_a_call_that_raises_is_still_timed_and_unwrapped():
    bench = _bench()

    class Owner:
        @staticmethod
        def boom():
            raise ValueError("x")
    original = Owner.boom
    try:
        with bench.CallClock(Owner, ("boom",)) as clock:
            Owner.boom()
    except ValueError:
        pass
    assert clock.calls == 1 and clock.seconds > 0
    assert Owner.boom is original
