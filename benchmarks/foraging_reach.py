"""Paper 000's Table 3 setting (10 robots, 3 objects of 40 wu, U_max 50-150, shipped model) in the in-process
foraging world: wu moved and objects done per run for Greedy and DR NM_I (``late: all``, the paper's rule, and
``late: fastest``), at several values of ``reach`` (how close to the object a robot loads) and ``delivery_reach``
(how close to the delivery point it unloads, the delivery area; ``same``: equal to ``reach``, a point D).

    python benchmarks/foraging_reach.py [--reach 0.3,0.75,1.0] [--delivery-reach same,1.0] [--seeds 1,2]
                                        [--time-limit 900] [--late all,fastest] [--min-distance 2]
                                        [--min-angle 90] [--no-greedy]
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sitl.experiments import dr_common as D  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reach", default="0.3,0.75,1.0")
    ap.add_argument("--delivery-reach", default="1.0", help="comma list of m, or same (= reach: a point D)")
    ap.add_argument("--seeds", default="1,2")
    ap.add_argument("--time-limit", type=float, default=900.0)
    ap.add_argument("--late", default="all", help="DR's late rules to run, comma list of all|fastest")
    ap.add_argument("--min-distance", type=float, default=D.Setup.min_distance,
                    help="m from D's centre objects appear at the least")
    ap.add_argument("--min-angle", type=float, default=D.Setup.min_angle,
                    help="deg apart objects appear, seen from D")
    ap.add_argument("--no-greedy", action="store_true", help="run DR only")
    args = ap.parse_args()
    logging.disable(logging.WARNING)
    from sitl.foraging import harness

    model = D.shipped_model()
    cells = [] if args.no_greedy else [("Greedy", D.Cell("Greedy", auction="greedy", strategy="NM_NI"))]
    cells += [(f"DR NM_I late={late}", D.Cell("NM_I", late=late)) for late in args.late.split(",")]
    print("reach  at D   seed  method                wu moved  objects done  wall (s)")
    for reach, at_d in [(float(r), float(r) if d == "same" else float(d))
                        for r in args.reach.split(",") for d in args.delivery_reach.split(",")]:
        setup = D.Setup(time_limit=args.time_limit, u_max=(50, 150), min_distance=args.min_distance,
                        min_angle=args.min_angle, delivery_area=at_d)
        for seed in map(int, args.seeds.split(",")):
            for name, cell in cells:
                cfg = D.config(cell, setup, seed, model)
                cfg = replace(cfg, options=replace(cfg.options, reach=reach))     # the area comes with the setup
                t0 = time.perf_counter()
                fr = harness.ForagingRun(cfg)
                try:
                    res = fr.run()
                finally:
                    fr.close()
                print(f"{reach:5.2f}  {at_d:5.2f}  {seed:4d}  {name:20s}  {res.moved:8.0f}  {len(res.finished):12d}  "
                      f"{time.perf_counter() - t0:8.0f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
