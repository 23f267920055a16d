"""The shipped fleets on a lossy network: each fleet of configs/fleets in lock-step (deterministic per seed) with
every robot's link leaving ``--loss`` of its datagrams to each peer unsent, independently and in spells of a
mean ``--burst`` s (``comms.peer_loss``, ``comms.loss_burst``), beside the same seed without loss.  The same as
``mrta sitl run configs/fleets/NAME.yaml --lockstep [--peer-loss P] [--loss-burst S] --seed N`` for each cell.

    PYTHONPATH=. python benchmarks/fleets_loss.py [--fleets create2_4,can_2,...] [--seeds 1-2] [--loss 0.1]
                                                  [--burst 2] [--jobs 2 | --cluster local|tcp://HOST:PORT]

One line a run (verdict, simulated time, the pose filters' relocalisations, idle robots' cycles making way, and
for a formation its global cost above the Hungarian optimum), then a table per fleet: goals met without loss, at
the loss, in spells, with the formations' gaps.  operator_4 waits for an operator and is
left out.
"""
from __future__ import annotations

import argparse
import logging
import math
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runtime.errors import InputError  # noqa: E402
from sitl.experiments import executor  # noqa: E402  (--jobs / --cluster: the sweep executor)

FLEETS = ("create2_4", "create2_4_boxes", "create2_10", "pioneer_4", "mixed_4", "coalition_6", "can_2",
          "foraging_4_member", "comutar_3")


def one(job: tuple[str, int, float, float]) -> dict:
    from tests.sitl_util import lockstep_run, worker_fleet

    name, seed, loss, burst = job
    logging.disable(logging.WARNING)

    def read(f) -> tuple[int, int]:
        daemons = [r.daemon for r in f.robots.values() if r.daemon is not None]
        return sum(d.core.ekf.stats.relocalised for d in daemons), sum(d.core.executive.made_way for d in daemons)

    with tempfile.TemporaryDirectory(prefix="fleets-loss-") as tmp:
        res, (reloc, made_way) = lockstep_run(worker_fleet(Path(tmp), f"{name}.yaml", seed, peer_loss=loss,
                                                           loss_burst=burst), Path(tmp) / "run", read)
    gap = None                          # a formation's global cost above the Hungarian optimum, %
    if res.get("optimum") and math.isfinite(res.get("global_cost", math.nan)):
        gap = 100.0 * (res["global_cost"] - res["optimum"]) / res["optimum"]
    return {"fleet": name, "seed": seed, "loss": loss, "burst": burst, "goal": res["goal_met"],
            "verdict": res["verdict"], "sim": res["sim_time"], "reloc": reloc, "made_way": made_way, "gap": gap}


def cell(rows: list[dict]) -> str:
    met = [r for r in rows if r["goal"]]
    missed = ", ".join(f"seed {r['seed']} ({r['verdict'][:60]})" for r in rows if not r["goal"])
    gaps = [r["gap"] for r in rows if r["gap"] is not None]
    gap = f" (gap {', '.join(f'{g:+.1f} %' for g in gaps)})" if gaps else ""
    return f"{len(met)}/{len(rows)}{gap}" + (f"; not met: {missed}" if missed else "")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fleets", default=",".join(FLEETS))
    ap.add_argument("--seeds", default="1-2", help="a range lo-hi, inclusive (default 1-2)")
    ap.add_argument("--loss", type=float, default=0.1, help="comms.peer_loss of every robot (default 0.1)")
    ap.add_argument("--burst", type=float, default=2.0, help="mean s of a loss spell for the third column (default 2)")
    executor.add_arguments(ap, jobs=2)
    args = ap.parse_args()
    try:
        executor.check_arguments(args)
    except InputError as exc:
        ap.error(str(exc))
    try:
        fleets = args.fleets.split(",")
        lo, hi = (int(x) for x in args.seeds.split("-"))
        if not set(fleets) <= set(FLEETS) or hi < lo or not 0 < args.loss <= 1 or not 0 < args.burst <= 3600:
            raise ValueError
    except ValueError:
        ap.error(f"--fleets {args.fleets!r} --seeds {args.seeds!r} --loss {args.loss} --burst {args.burst}: expected "
                 f"fleets among {','.join(FLEETS)}, seeds LO-HI, a loss in (0, 1] and a burst in (0, 3600] s")
    modes = ((0.0, 0.0), (args.loss, 0.0), (args.loss, args.burst))
    jobs = [(f, s, loss, burst) for f in fleets for s in range(lo, hi + 1) for loss, burst in modes]
    rows = []
    for _, r in executor.run_each(one, [(job,) for job in jobs], args.jobs, args.cluster):
        rows.append(r)
        print(f"{r['fleet']:18s} seed {r['seed']} loss {r['loss']:g} spells {r['burst']:g} s: "
              f"{'goal met' if r['goal'] else 'NOT MET'} at {r['sim']:.1f} s, relocalised {r['reloc']}, "
              f"making way {r['made_way']} cycles" + ("" if r["gap"] is None else f", gap {r['gap']:+.2f} %"),
              flush=True)
    print(f"\n| fleet | no loss | {100 * args.loss:g} % | {100 * args.loss:g} % in {args.burst:g} s spells |")
    print("| --- | --- | --- | --- |")
    for f in fleets:
        cols = [cell([r for r in rows if r["fleet"] == f and (r["loss"], r["burst"]) == m]) for m in modes]
        print(f"| {f} | " + " | ".join(cols) + " |")
    return 0 if all(r["goal"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
