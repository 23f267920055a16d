"""How long the daemons' formation agents (runtime/allocation/formation/family.py: rounds around each method's solver)
take to settle a 10-robot ring formation on a lossy link: the in-memory bus with kinematic robots
(runtime/inprocess.py: robot cores with kinematic motion), ten robots in a line, ten station-keeping positions on a 2.5 m ring handed to robot 1,
``--drops`` of the messages lost (5 ms of jitter), one run per seed (tests/test_formation_fleet.py ``settle``).  A
run settles when every robot holds one task, every task is held, and every robot's rounds have converged; it then
runs 300 s more, and the time in it when some task was held by two robots or by none is counted.

    PYTHONPATH=. python benchmarks/formation_loss.py [--methods auction,bs,rtma] [--drops 0,0.1] [--seeds 1-12]

Prints per method and loss: how many runs settled within ``--limit`` s (600), the median and largest time to
settle, and the runs whose settled formation broke afterwards, with for how long.
"""
from __future__ import annotations

import argparse
import logging
import math
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.test_formation_fleet import settle  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--methods", default="auction,bs,rtma")
    ap.add_argument("--drops", default="0,0.1")
    ap.add_argument("--seeds", default="1-12", help="a range lo-hi, inclusive (default 1-12)")
    ap.add_argument("--limit", type=float, default=600.0, help="simulated s to settle (default 600)")
    args = ap.parse_args()
    try:
        methods = args.methods.split(",")
        drops = [float(d) for d in args.drops.split(",")]
        lo, hi = (int(x) for x in args.seeds.split("-"))
        if not set(methods) <= {"auction", "bs", "rtma"} or not all(0 <= d < 1 for d in drops) or hi < lo:
            raise ValueError
    except ValueError:
        ap.error(f"--methods {args.methods!r} --drops {args.drops!r} --seeds {args.seeds!r}: expected methods among "
                 "auction,bs,rtma, losses in [0, 1) and seeds LO-HI")
    logging.disable(logging.WARNING)
    for method in methods:
        for drop in drops:
            runs = [settle(method, drop, seed, args.limit) for seed in range(lo, hi + 1)]
            took = [t for t, _ in runs if math.isfinite(t)]
            broken = {seed: b for seed, (t, b) in zip(range(lo, hi + 1), runs) if math.isfinite(t) and b > 0}
            spread = f"median {statistics.median(took):.1f} s, largest {max(took):.1f} s" if took else "-"
            where = ", ".join(f"seed {k}: {b:.1f} s" for k, b in broken.items()) or "none"
            print(f"{method:8s} {100 * drop:4.0f} % loss: {len(took)}/{len(runs)} settled within {args.limit:g} s "
                  f"({spread}); broken in the 300 s after: {where}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
