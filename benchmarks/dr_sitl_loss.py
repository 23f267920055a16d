"""Issue 16's lossy-network properties in SITL, over many seeds: configs/fleets/foraging_4.yaml (four Pioneer daemons,
two objects, O1's leader killed and withdrawn once it has a member) in lock-step (deterministic per seed), with
every robot's link leaving ``--loss`` of its datagrams to each peer unsent (``comms.peer_loss``), and the fleet's
``seed`` set to each of [from, to).  After every control cycle the daemons' agents are checked as
tests/test_dr_fleet.py checks the kinematic fleet's (tests/dr_util.py ``Watch``): no robot in two groups in its own
view nor holding two commitments, a leader's member list stale for at most member_timeout, no object with two
leaders for longer than three LEADER_ALIVE periods.

    PYTHONPATH=. python benchmarks/dr_sitl_loss.py --from 1 --to 11 [--loss 0.1] [--burst 0] [--carrier-leads] [--jobs 2 | --cluster local|tcp://HOST:PORT]

One line a run (goal, the new leader's delay after the kill, the share of peer datagrams lost, the longest spell of
two leaders and of a stale member, violations), then the spread.  tests/test_sitl_foraging.py runs seed 1.
"""
from __future__ import annotations

import argparse
import logging
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runtime.errors import InputError  # noqa: E402
from sitl.experiments import executor  # noqa: E402  (--jobs / --cluster: the sweep executor)


def one(job: tuple[int, float, float, bool]) -> dict:
    from tests.dr_util import DaemonsWatch
    from tests.sitl_util import lockstep_run, robot_template, worker_fleet

    seed, loss, burst, carrier_leads = job
    logging.disable(logging.WARNING)

    def read(f) -> tuple[int, int]:
        links = [r.daemon.link.counters for r in f.robots.values()]
        return sum(c.loss_injected for c in links), sum(c.peer_sent for c in links)

    with tempfile.TemporaryDirectory(prefix="dr-sitl-loss-") as tmp:
        changes = {}
        if carrier_leads:                # foraging_4's robot template with the DR option on
            changes["robot"] = str(robot_template(Path(tmp), ROOT / "configs" / "robots" / "pioneer3dx_forage.yaml",
                                                  "carrier_leads.yaml", carrier_leads=True))
        watch = DaemonsWatch()
        res, (lost, sent) = lockstep_run(worker_fleet(Path(tmp), "foraging_4.yaml", seed, peer_loss=loss,
                                                      loss_burst=burst, **changes), Path(tmp) / "run", read, watch)
    kill = res.get("kill") or {}
    return {"seed": seed, "goal": res["goal_met"], "verdict": res["verdict"], "sim": res["sim_time"],
            "after": kill.get("after"), "lost": lost / max(lost + sent, 1), "dual": watch.longest_dual,
            "stale": watch.longest_stale, "violations": watch.violations}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--from", dest="lo", type=int, default=1)
    ap.add_argument("--to", dest="hi", type=int, default=11)
    ap.add_argument("--loss", type=float, default=0.1, help="comms.peer_loss of every robot (default 0.1)")
    ap.add_argument("--burst", type=float, default=0.0, help="comms.loss_burst: mean s of a loss spell (default 0)")
    ap.add_argument("--carrier-leads", action="store_true",
                    help="DR option carrier_leads: a robot with a load of a leaderless task may ask to lead it")
    executor.add_arguments(ap, jobs=2)
    args = ap.parse_args()
    try:
        executor.check_arguments(args)
    except InputError as exc:
        ap.error(str(exc))
    if not 0.0 <= args.loss <= 1.0 or args.hi <= args.lo or not 0.0 <= args.burst <= 3600.0:
        ap.error(f"--loss {args.loss} / --burst {args.burst} / --from {args.lo} --to {args.hi}: expected a share 0..1, "
                 "a burst 0..3600 s and from < to")
    rows = []
    tasks = [((seed, args.loss, args.burst, args.carrier_leads),) for seed in range(args.lo, args.hi)]
    for _, r in executor.run_each(one, tasks, args.jobs, args.cluster):
        rows.append(r)
        after = "-" if r["after"] is None else f"{r['after']:.1f} s"
        print(f"seed {r['seed']:3d}: {'goal met' if r['goal'] else 'NOT MET'} in {r['sim']:5.1f} s, new leader "
              f"{after} after the kill, {100 * r['lost']:.1f} % of peer datagrams lost, two leaders at most "
              f"{r['dual']:.2f} s, a stale member at most {r['stale']:.2f} s, {len(r['violations'])} violations"
              + (f": {r['violations'][:2]}" if r["violations"] else ""), flush=True)
    afters = [r["after"] for r in rows if r["after"] is not None]
    burst = f" in spells of {args.burst:g} s" if args.burst else ""
    print(f"\n{len(rows)} runs at {100 * args.loss:g} % loss{burst}: goal met in {sum(r['goal'] for r in rows)}, "
          f"{sum(bool(r['violations']) for r in rows)} with a violation; new leader after the kill "
          f"{min(afters):.1f}-{max(afters):.1f} s (median {np.median(afters):.1f}); longest two leaders "
          f"{max(r['dual'] for r in rows):.2f} s, longest stale member {max(r['stale'] for r in rows):.2f} s"
          if afters else f"\n{len(rows)} runs: no kill happened")
    return 0 if all(r["goal"] and not r["violations"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
