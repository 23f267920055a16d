"""How often robots touch each other in a shipped fleet: a lock-step run (deterministic per seed) with the
pybullet contact points between robot bodies read after every control cycle.  An episode is a pair of robots
coming into contact; the cycles in contact count how long they stayed.  Sensorless robots (Create, CAN base)
find each other only by their bumpers, so this is their collision rate.

    PYTHONPATH=. python benchmarks/robot_contacts.py [--fleets create2_10,coalition_6] [--seeds 1-2] [--loss 0]

One line a run: verdict, simulated time, contact episodes, control cycles with a contact, the first episodes.
"""
from __future__ import annotations

import argparse
import logging
import sys
import tempfile
from pathlib import Path

import pybullet as p

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


class Contacts:
    """``on_step`` for ``launcher.run_lockstep``: robot-robot contact episodes and cycles in contact."""

    def __init__(self):
        self.episodes: list[tuple[float, tuple[int, int]]] = []
        self.cycles = 0
        self._touching: set = set()

    def __call__(self, f) -> None:
        ids = {b.body_id: rid for rid, b in f.world.bodies.items()}
        now = {tuple(sorted((ids[a], ids[c[2]])))
               for a in ids for c in p.getContactPoints(bodyA=a, physicsClientId=f.world.client_id) if c[2] in ids}
        self.episodes += [(round(f.world.t, 1), pair) for pair in sorted(now - self._touching)]
        self._touching = now
        self.cycles += bool(now)


def main() -> int:
    from tests.sitl_util import lockstep_run, worker_fleet

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fleets", default="create2_10,coalition_6")
    ap.add_argument("--seeds", default="1-2", help="a range lo-hi, inclusive (default 1-2)")
    ap.add_argument("--loss", type=float, default=0.0, help="comms.peer_loss of every robot (default 0)")
    args = ap.parse_args()
    try:
        lo, hi = (int(x) for x in args.seeds.split("-"))
        if hi < lo or not 0.0 <= args.loss <= 1.0:
            raise ValueError
    except ValueError:
        ap.error(f"--seeds {args.seeds!r} --loss {args.loss}: expected seeds LO-HI and a loss in [0, 1]")
    logging.disable(logging.WARNING)
    for name in args.fleets.split(","):
        for seed in range(lo, hi + 1):
            with tempfile.TemporaryDirectory(prefix="robot-contacts-") as tmp:
                seen = Contacts()
                res, _ = lockstep_run(worker_fleet(Path(tmp), f"{name}.yaml", seed, peer_loss=args.loss),
                                      Path(tmp) / "run", on_step=seen)
            print(f"{name} seed {seed} loss {args.loss:g}: {res['verdict'][:40]} at {res['sim_time']:.1f} s; "
                  f"{len(seen.episodes)} contact episodes, {seen.cycles} control cycles in contact: "
                  f"{seen.episodes[:6]}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
