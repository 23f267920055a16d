"""Per-step trace of foraging runs, to hold speed work to bit-identical behaviour.

Records, for every control period of a few fixed-seed runs, every robot's pose (after the world step) and the
command its executive gave (bit for bit: float64 arrays), and writes them to an ``.npz``.  ``compare`` says
whether two traces are identical and, if not, where they first part.

Runs: calibration mode (no agents) with 8 robots on one object for 120 s; the test stand-in agent with 10
robots and 3 objects for 120 s (seed 1); the DR agent with 10 robots and 3 objects for 120 s (seed 2).

Usage (from the worktree root):
  PYTHONPATH=. python benchmarks/foraging_trace.py record /tmp/before.npz
  PYTHONPATH=. python benchmarks/foraging_trace.py compare /tmp/before.npz /tmp/after.npz
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sitl.foraging.harness import ForagingConfig, ForagingRun  # noqa: E402


def runs(seconds: float) -> dict[str, ForagingConfig]:
    from tests.foraging_standin import STANDIN, StandInOptions
    return {
        "jam8": ForagingConfig(robots=8, method=None, time_limit=seconds, fixed_object=(1.4, 0.0), seed=1),
        "standin10": ForagingConfig(robots=10, method=STANDIN, options=StandInOptions(), time_limit=seconds, seed=1),
        "dr10": ForagingConfig(robots=10, method="dr", time_limit=seconds, seed=2),
    }


def trace(cfg: ForagingConfig) -> tuple[np.ndarray, np.ndarray, float]:
    """(steps, robots, 3) poses, (steps, robots, 2) commands, wall seconds."""
    fr = ForagingRun(cfg)
    world = fr.world
    cmds = np.full((len(world.ids), 2), np.nan)
    inner = world.command

    def command(robot, v, w):
        cmds[world.index[robot]] = (v, w)
        inner(robot, v, w)

    world.command = command
    poses, commands = [], []

    def observe(run):
        poses.append(run.world.poses.copy())
        commands.append(cmds.copy())
        cmds[:] = np.nan

    t0 = time.perf_counter()
    try:
        fr.run(observe)
    finally:
        fr.close()
    return np.array(poses), np.array(commands), time.perf_counter() - t0


def record(out: str, seconds: float) -> None:
    arrays = {}
    for name, cfg in runs(seconds).items():
        poses, commands, wall = trace(cfg)
        arrays[f"{name}_poses"], arrays[f"{name}_commands"] = poses, commands
        print(f"{name}: {len(poses)} steps, {wall:.1f} s wall")
    np.savez(out, **arrays)


def compare(a: str, b: str) -> bool:
    x, y = np.load(a), np.load(b)
    same = True
    for key in sorted(set(x.files) | set(y.files)):
        if key not in x.files or key not in y.files:
            print(f"{key}: only in one trace")
            same = False
            continue
        p, q = x[key], y[key]
        if p.shape == q.shape and np.array_equal(p.view(np.uint64), q.view(np.uint64)):
            print(f"{key}: identical ({p.shape[0]} steps)")
            continue
        same = False
        n = min(len(p), len(q))
        diff = [i for i in range(n) if not np.array_equal(p[i].view(np.uint64), q[i].view(np.uint64))]
        first = diff[0] if diff else n
        print(f"{key}: DIFFERENT, shapes {p.shape} {q.shape}, first differing step {first}")
    return same


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("out")
    r.add_argument("--seconds", type=float, default=120.0)
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    args = ap.parse_args()
    if args.cmd == "record":
        record(args.out, args.seconds)
    else:
        sys.exit(0 if compare(args.a, args.b) else 1)


if __name__ == "__main__":
    main()
