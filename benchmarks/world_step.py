"""Steps per second and real-time factor of the SITL world with 1, 4 and 10 Create 2 robots.

The robots drive a slow arc (every body moving, floor contacts active), stepped one ``dt`` per call as
the launcher does.  The real-time factor (RTF) is sim seconds per CPU second of this process
(``time.process_time``); it must be >= 10 for 10 robots.  As a peer measured in the same run, the
same world with pybullet's defaults (50 solver iterations, every manifold point solved) is timed and
the ratio printed.  Usage: python benchmarks/world_step.py [--seconds SIM_S] [--dt DT]
"""
from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import pybullet as p

from runtime.config import load_world
from sitl import world as world_mod
from sitl.world import World

ROOT = Path(__file__).resolve().parents[1]


def run(n_robots: int, sim_seconds: float, dt: float, defaults: bool = False) -> tuple[float, float]:
    """Return (steps per CPU second, real-time factor) for ``n_robots`` driving for ``sim_seconds``."""
    w = World(load_world(ROOT / "configs" / "worlds" / "arena_10m.yaml"), seed=1, dt=dt)
    try:
        if defaults:
            p.setPhysicsEngineParameter(numSolverIterations=50, physicsClientId=w.client_id)
        for k in range(n_robots):
            ang = 2 * math.pi * k / n_robots
            bot = w.add_body(k + 1, (2.5 * math.cos(ang), 2.5 * math.sin(ang), ang + math.pi / 2), "create2")
            bot.set_wheel_speeds(0.25, 0.3)
            if defaults:
                for link in range(-1, p.getNumJoints(bot.body_id, physicsClientId=w.client_id)):
                    p.changeDynamics(bot.body_id, link, contactProcessingThreshold=1e30, physicsClientId=w.client_id)
        w.step(10)
        steps = int(round(sim_seconds / dt))
        t0 = time.process_time()
        for _ in range(steps):          # one call per step, as the launcher services devices every step
            w.step()
        cpu = time.process_time() - t0
    finally:
        w.close()
    return steps / cpu, sim_seconds / cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="simulated seconds per run")
    ap.add_argument("--dt", type=float, default=1 / 200, help="physics step (s)")
    args = ap.parse_args()
    print(f"dt = {args.dt:.4f} s, solver iterations {world_mod.SOLVER_ITERATIONS}, {args.seconds:g} sim s per run")
    print(f"{'robots':>6} {'steps/s':>10} {'RTF':>8} {'RTF(defaults)':>14} {'ratio':>6}")
    for n in (1, 4, 10):
        sps, rtf = run(n, args.seconds, args.dt)
        _, rtf_peer = run(n, args.seconds, args.dt, defaults=True)
        print(f"{n:>6} {sps:>10.0f} {rtf:>8.1f} {rtf_peer:>14.1f} {rtf / rtf_peer:>6.2f}")


if __name__ == "__main__":
    main()
