"""Messages and rounds: epsilon-scaling auction vs RTMA and BS on the same instances, one run each.

Robots and tasks uniform in a 1000 x 1000 m field (paper 002, section IV-A), straight-line costs,
in-memory bus (one-way delay ``--delay``, 10 ms by default; lossless unless ``--drop``).  Per size and method: messages sent (a broadcast counts once),
rounds (longest causal chain of messages), simulated seconds to convergence, % error against the
Hungarian optimum, and messages / CPU time as ratios to RTMA measured in the same run.

``--errors`` also prints the % error of BS and RTMA against the optimum over ``--cases`` random
instances per size 2..20 (paper Fig. 6/7: mean error at 20 robots, mean over sizes of the max error).

Usage: python benchmarks/auction_messages.py [--sizes 20 100] [--seed 1] [--delay S] [--drop P] [--errors] [--cases 100]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from runtime.allocation.formation.assignment import hungarian, percent_error, straight_line_costs
from runtime.allocation.formation.simulate import BusParams, solve
from sitl.experiments.formation_common import error_sweep, mean_of_max, uniform_instance

METHODS = ("auction", "rtma", "bs")


def compare(sizes, seed, drop=0.0, delay=0.01):
    print(f"{'n':>4} {'method':>8} {'messages':>9} {'x RTMA':>7} {'rounds':>7} {'sim s':>7} "
          f"{'error %':>8} {'cpu x RTMA':>10}")
    for n in sizes:
        robots, tasks = uniform_instance(np.random.default_rng(seed + n), n)
        optimum = hungarian(straight_line_costs(robots, tasks))[1]
        rows = {}
        for m in METHODS:
            t0 = time.process_time()
            bus = BusParams(delay=delay, seed=seed, drop=drop, duplicate=drop, jitter=0.01 if drop else 0.0)
            r = solve(m, robots=robots, tasks=tasks, bus=bus, until=3600)
            rows[m] = (r, time.process_time() - t0)
        base_msgs, base_cpu = rows["rtma"][0].messages, rows["rtma"][1]
        for m, (r, cpu) in rows.items():
            flag = "" if r.converged else "  NOT CONVERGED"
            print(f"{n:>4} {m:>8} {r.messages:>9} {r.messages / base_msgs:>7.2f} {r.rounds:>7} {r.sim_time:>7.2f} "
                  f"{percent_error(r.cost, optimum):>8.2f} {cpu / base_cpu:>10.2f}{flag}")


def errors(cases, seed, sizes=range(2, 21)):
    """The sweep of ``mrta experiment formation-ideal`` (same instances for the same seed), BS and RTMA."""
    print(f"\n% error vs Hungarian, {cases} random cases per size, 1000 x 1000 m field")
    print(f"{'n':>4} {'BS mean':>8} {'BS max':>8} {'RTMA mean':>10} {'RTMA max':>9}")
    rows = error_sweep(uniform_instance, sizes, cases, seed, ("bs", "rtma"))
    for r in rows:
        assert r["not_converged"] == 0, r
    get = {(r["robots"], r["method"]): r for r in rows}
    for n in sizes:
        bs, rtma = get[(n, "bs")], get[(n, "rtma")]
        print(f"{n:>4} {bs['mean_error_pct']:>8.2f} {bs['max_error_pct']:>8.2f} "
              f"{rtma['mean_error_pct']:>10.2f} {rtma['max_error_pct']:>9.2f}")
    print(f"mean over sizes of the max error: BS {mean_of_max(rows, 'bs'):.2f} %, RTMA {mean_of_max(rows, 'rtma'):.2f} %"
          "  (paper: 33.77 %, 14.91 %)")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[20, 100])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--delay", type=float, default=0.01, help="one-way message delay in seconds (default 0.01)")
    ap.add_argument("--drop", type=float, default=0.0,
                    help="loss and duplication probability per copy (adds 10 ms jitter: reordering)")
    ap.add_argument("--errors", action="store_true", help="also the BS/RTMA error sweep (about a minute)")
    ap.add_argument("--cases", type=int, default=100)
    args = ap.parse_args()
    compare(args.sizes, args.seed, args.drop, args.delay)
    if args.errors:
        errors(args.cases, args.seed)


if __name__ == "__main__":
    main()
