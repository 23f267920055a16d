"""Many seeds of the lossy-fleet property (tests/test_dr_fleet.py): 10 robots, 12 objects, 10 % of messages
dropped, 2 % duplicated, each seed run with dr, sr and greedy.  A run is bad when the Watch saw a violation (a
robot in two coalitions, a stale member list, two leaders of a task past three LEADER_ALIVE periods) or the books
fail (weight delivered, table state, one DONE per task).  The property test draws 12 random seeds per CI run;
this looks for the rare ones, which then become its explicit examples.

    PYTHONPATH=. python benchmarks/dr_lossy_sweep.py --from 0 --to 150 [--mult 13 --add 5] [--strategies ...]
                                                     [--carrier-leads]

Seed k of [from, to) is ``k * mult + add``; its strategy cycles through ``--strategies`` by k.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runtime.allocation.dr.options import DrOptions  # noqa: E402
from tests.test_dr_fleet import TEN, _lossy, check_books  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--from", dest="lo", type=int, default=0)
    ap.add_argument("--to", dest="hi", type=int, default=150)
    ap.add_argument("--mult", type=int, default=13)
    ap.add_argument("--add", type=int, default=5)
    ap.add_argument("--strategies", default="M_NI,NM_NI,M_I,NM_I")
    ap.add_argument("--carrier-leads", action="store_true", help="DR option carrier_leads on")
    args = ap.parse_args()
    strategies = args.strategies.split(",")
    bad = runs = asked = 0
    for k in range(args.lo, args.hi):
        seed, strategy = k * args.mult + args.add, strategies[k % len(strategies)]
        for auction in ("dr", "sr", "greedy"):
            f, watch, handed = _lossy(seed, TEN, 12, DrOptions(auction=auction, strategy=strategy,
                                                                      carrier_leads=args.carrier_leads))
            runs += 1
            try:
                check_books(f, handed)
                books = ""
            except AssertionError as exc:
                books = f"books: {exc!r}"
            asked += sum(f.robots[r].agent.carrier_requests for r in f.robots)
            if watch.violations or books:
                bad += 1
                print(f"seed {seed} {auction} {strategy}: {watch.violations[:1]} {books}", flush=True)
        print(f"  {k + 1 - args.lo}/{args.hi - args.lo} seeds, {bad} bad", file=sys.stderr, flush=True)
    print(f"bad {bad} of {runs} runs" + (f"; carriers asked to lead {asked} times" if args.carrier_leads else ""))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
