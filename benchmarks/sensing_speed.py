"""Cost of the SITL's ray-cast sensing: a 360-beam laser scan at 10 Hz for 10 robots beside the Pioneer sonar ring.

Ten Pioneer 3-DX bodies stand in the 10 m arena among its obstacles, each carrying an RPLIDAR A1
(:mod:`sitl.devices.rplidar`, 360 steps a revolution, 12 m) and its 16-sonar ring (:mod:`sitl.bodies.pioneer3dx`,
five rays a cone, 5 m).  Timed in CPU seconds of this process (``time.process_time``), the best of ``--repeat``:

* one full scan of every robot's laser, all 3600 rays in one :func:`sitl.sensing.raycast.cast_many` call, and the
  same robot by robot (ten calls);
* one full ring of every robot's sonar (800 rays), batched and robot by robot;
* why the planar foraging world keeps its closed-form ring (:func:`sitl.sensing.sonar_ring.ring_ranges`, discs and
  walls only): the same ring by ray casts there (five rays a cone
  from the same transducer poses, the nearest), its cost and how many of its readings differ from the closed form;
* the emulators as the launcher runs them: ten :class:`~sitl.devices.rplidar.RplidarDevice` serviced every 5 ms
  of sim time (each casts the nodes due every 16 ms), per sim second.

"CPU at 10 Hz" is the share of one core a 10 Hz refresh of that row takes.  The batched and robot-by-robot
distances are compared bit for bit.  Usage: python benchmarks/sensing_speed.py [--repeat N]
"""
from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from runtime.config import load_world
from sitl.bodies.pioneer3dx import sonar_rays
from sitl.devices.rplidar import RplidarDevice
from sitl.foraging import world as foraging
from sitl.sensing import raycast, sonar_ring
from sitl.world import World

ROOT = Path(__file__).resolve().parents[1]
N_ROBOTS = 10


class _Sink:
    """A link that takes every byte (no pty: the benchmark times the sensing, not the kernel)."""
    path = "sink"

    def read(self) -> bytes:
        return b""

    def write(self, data: bytes) -> int:
        return len(data)

    def close(self) -> None:
        pass


class _Disc:
    """A foraging robot as a beam carrier: its body id and client (its pose comes from the world's table)."""

    def __init__(self, body_id: int, kw: dict):
        self.body_id, self._kw = body_id, kw


def planar_ring(repeat: int) -> tuple[float, float, int, int, float]:
    """(closed-form ms, ray-cast ms, readings that differ by > 1 mm, readings, largest difference m) for 10 discs."""
    starts = {k + 1: (3.0 * math.cos(2 * math.pi * k / N_ROBOTS), 3.0 * math.sin(2 * math.pi * k / N_ROBOTS),
                      2 * math.pi * k / N_ROBOTS + 2.0) for k in range(N_ROBOTS)}
    world = foraging.ForagingWorld(starts, size=8.0)
    try:
        rays = sonar_rays()
        sets = [raycast.Beams(_Disc(b, world._kw), rays, foraging.HEIGHT, sonar_ring.MAX_RANGE) for b in world.bodies]
        poses = [tuple(r) for r in world.poses]

        def by_rays():
            dists, _ = raycast.cast_many(sets, poses, world._kw)
            out = np.full((N_ROBOTS, sonar_ring.N_SONARS), np.inf)
            for k, d in enumerate(dists):
                np.minimum.at(out[k], rays[:, 3].astype(int), d)
            return np.where(out < sonar_ring.MIN_RANGE, sonar_ring.MAX_RANGE, out)
        closed = sonar_ring.ring_ranges(world.poses, world.radius, world.size / 2)
        cast = by_rays()
        diff = np.abs(closed - cast)
        return (best(lambda: sonar_ring.ring_ranges(world.poses, world.radius, world.size / 2), repeat) * 1e3,
                best(by_rays, repeat) * 1e3, int(np.sum(diff > 1e-3)), diff.size, float(diff.max()))
    finally:
        world.close()


def best(fn, repeat: int) -> float:
    out = math.inf
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        out = min(out, time.process_time() - t0)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=20, help="timed repetitions per row (the best is shown)")
    args = ap.parse_args()
    with World(load_world(ROOT / "configs" / "worlds" / "arena_10m.yaml"), seed=1) as w:
        bodies = []
        for k in range(N_ROBOTS):
            ang = 2 * math.pi * k / N_ROBOTS
            bodies.append(w.add_body(k + 1, (3.5 * math.cos(ang), 3.5 * math.sin(ang), ang + 1.0), "pioneer3dx"))
        w.step(40)
        devs = [RplidarDevice(b, "a1", link=_Sink(), seed=k) for k, b in enumerate(bodies)]
        steps = np.arange(devs[0].model.samples)
        lasers = [d.beams(steps) for d in devs]
        sonars = [b.sonar for b in bodies]

        batched, n_laser = raycast.cast_many(lasers)
        alone = [raycast.cast_many([s])[0][0] for s in lasers]
        same = all(np.array_equal(a, b) for a, b in zip(batched, alone))
        s_batched, n_sonar = raycast.cast_many(sonars)
        s_same = all(np.array_equal(a, raycast.cast_many([s])[0][0]) for a, s in zip(s_batched, sonars))

        rows = [
            (f"laser 360 x {N_ROBOTS}, one batch", n_laser, best(lambda: raycast.cast_many(lasers), args.repeat)),
            (f"laser 360 x {N_ROBOTS}, robot by robot", n_laser,
             best(lambda: [raycast.cast_many([s]) for s in lasers], args.repeat)),
            (f"sonar 16x5 x {N_ROBOTS}, one batch", n_sonar, best(lambda: raycast.cast_many(sonars), args.repeat)),
            (f"sonar 16x5 x {N_ROBOTS}, robot by robot", n_sonar,
             best(lambda: [raycast.cast_many([s]) for s in sonars], args.repeat)),
        ]
        print(f"{N_ROBOTS} Pioneer 3-DX in arena_10m, best of {args.repeat}; CPU s by time.process_time")
        print(f"{'what':<40} {'rays':>6} {'ms':>8} {'rays/ms':>8} {'CPU at 10 Hz':>13}")
        for name, rays, sec in rows:
            print(f"{name:<40} {rays:>6} {sec * 1e3:8.2f} {rays / (sec * 1e3):8.0f} {sec * 10 * 100:12.1f}%")

        def serve_one_second():
            t0 = w.t
            for d in devs:
                d.scanning, d._t0, d._sent, d._batch_at = True, t0, 0, t0
            for i in range(1, 201):
                for d in devs:
                    d.service(t0 + i * 0.005)
        sec = best(serve_one_second, max(1, args.repeat // 5))
        nodes = sum(d.stats.nodes for d in devs) // max(1, args.repeat // 5)
        print(f"{'10 A1 emulators, 1 sim s at 5 ms steps':<40} {nodes:>6} {sec * 1e3:8.2f} "
              f"{nodes / (sec * 1e3):8.0f} {sec * 100:12.1f}% (of one core per sim s)")
        print(f"batched == robot by robot, bit for bit: laser {same}, sonar {s_same}")
    cf, rc, differ, total, worst = planar_ring(args.repeat)
    print(f"planar foraging world, {N_ROBOTS} discs: sonar ring closed form {cf:.2f} ms, by ray casts {rc:.2f} ms; "
          f"{differ} of {total} readings differ by > 1 mm (largest {worst:.3f} m)")


if __name__ == "__main__":
    main()
