"""How close the sensorless Create of configs/fleets/comutar_3.yaml comes to the pillars, over many seeds: the
fleet in lock-step (deterministic per seed, about 15-25 s of wall time a run), the fleet's ``seed`` set to each
of [from, to).  Prints one line a run (least clearance of the borrower's body to a pillar, when, the verdict)
and then the spread: runs that touched, the least clearances' minimum, 10th percentile and median, and how many
met the goal (every waypoint visited, no touch, stopped and re-allocated after the kill).

    PYTHONPATH=. python benchmarks/comutar_clearance.py --from 1 --to 41 [--jobs 2 | --cluster local|tcp://HOST:PORT] [--option feed_memory=0.5 ...]
                                                        [--peer-loss 0.1]

``--option NAME=VALUE`` sets an ``allocation:`` option of the borrower's robot config (the consumer of the
borrowed sensor) for every run: how the avoider's inputs are tuned.

tests/test_comutar_sitl.py runs the same fleet once, as daemon processes; this is its spread.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runtime.errors import InputError  # noqa: E402
from sitl.experiments import executor  # noqa: E402  (--jobs / --cluster: the sweep executor)


def one(job: tuple[int, dict, float]) -> dict:
    import logging

    import yaml

    from tests.sitl_util import lockstep_run, robot_template, worker_fleet

    seed, options, loss = job
    logging.disable(logging.WARNING)
    with tempfile.TemporaryDirectory(prefix="comutar-clearance-") as tmp:
        path = worker_fleet(Path(tmp), "comutar_3.yaml", seed, peer_loss=loss)
        if options:
            fleet = yaml.safe_load(path.read_text())
            borrower = fleet["scenario"]["borrower"]
            entry = next(r for r in fleet["robots"] if r["id"] == borrower)
            entry["robot"] = str(robot_template(Path(tmp), Path(entry.get("robot") or fleet["robot"]),
                                                "borrower.yaml", **options))
            path.write_text(yaml.safe_dump(fleet, sort_keys=False))
        res, _ = lockstep_run(path, Path(tmp) / "run")
    return {"seed": seed, "least": res["least_clearance"], "at": res["least_clearance_at"],
            "goal": res["goal_met"], "verdict": res["verdict"], "sim_time": res["sim_time"]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--from", dest="lo", type=int, default=1)
    ap.add_argument("--to", dest="hi", type=int, default=41)
    executor.add_arguments(ap, jobs=2)
    ap.add_argument("--option", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--peer-loss", type=float, default=0.0, metavar="P",
                    help="every robot's link loses this share of its datagrams to each peer (default 0)")
    args = ap.parse_args()
    try:
        executor.check_arguments(args)
    except InputError as exc:
        ap.error(str(exc))
    import yaml

    from dataclasses import fields

    from runtime.allocation.comutar.options import ComutarOptions

    known = {f.name for f in fields(ComutarOptions)} - {"method"}
    options = {}
    for item in args.option:
        name, sep, value = item.partition("=")
        if not sep or name not in known:
            ap.error(f"--option {item!r}: expected NAME=VALUE with NAME one of the comutar allocation options "
                     f"({', '.join(sorted(known))})")
        options[name] = yaml.safe_load(value)
    if not 0.0 <= args.peer_loss <= 1.0:
        ap.error(f"--peer-loss {args.peer_loss}: expected a share of datagrams 0..1")
    seeds = list(range(args.lo, args.hi))
    rows = []
    for _, r in executor.run_each(one, [((seed, options, args.peer_loss),) for seed in seeds], args.jobs, args.cluster):
        rows.append(r)
        at = "-" if r["at"] is None else f"{r['at']:.1f} s"
        print(f"seed {r['seed']:3d}: least clearance {r['least']:6.3f} m at {at:>8}, sim {r['sim_time']:5.1f} s: "
              f"{r['verdict']}", flush=True)
    least = np.array([r["least"] for r in rows])
    touched = int((least <= 0.0).sum())
    print(f"\n{len(rows)} runs: {touched} touched a pillar; least clearance min {least.min():.3f} m, "
          f"p10 {np.percentile(least, 10):.3f} m, median {np.median(least):.3f} m; goal met in "
          f"{sum(r['goal'] for r in rows)}; sim time median {np.median([r['sim_time'] for r in rows]):.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
