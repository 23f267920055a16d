"""`mrta wdp BIDS.json`: pick the winning coalition bids of one simultaneous allocation round."""
from __future__ import annotations

import argparse
import json
import sys

from runtime import argcheck
from runtime.allocation.coalition import winner_determination as wd
from runtime.errors import InputError


DEFAULT_TIME_LIMIT = 60.0        # s


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("wdp", help="winner determination for coalition bids (paper 001)",
                       description="Choose the bids with the largest total value such that no robot is in "
                                   "two winning coalitions and no task is won twice.  Exit 0 with the answer; 1 "
                                   "when the time limit is reached (one line on stderr: the best value found and "
                                   "a bound on the optimum); 2 for bad input (one line naming it).")
    p.add_argument("bids", metavar="BIDS.json",
                   help='{"robots": [ids], "tasks": [ids], "bids": [{"task", "robots", "value"}]} ("-" = stdin); '
                        f"values 0..{wd.MAX_VALUE:g}")
    p.add_argument("--method", default="auto", choices=wd.METHODS, help="solver (default: %(default)s)")
    p.add_argument("--node-limit", type=int, default=None,
                   help="stop IDA*/BFS after this many nodes (answer then marked capped)")
    p.add_argument("--time-limit", type=float, default=DEFAULT_TIME_LIMIT, metavar="S",
                   help="give up after S seconds of solving and exit 1 (default: %(default)g)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.node_limit is not None and args.node_limit < 1:
        raise InputError(f"--node-limit {args.node_limit}: expected a positive number of nodes")
    argcheck.number(args.time_limit, "--time-limit", 0.0, lo_open=True)
    problem = wd.load_problem(args.bids)
    try:
        result = wd.solve(problem, args.method, node_limit=args.node_limit, time_limit=args.time_limit)
    except wd.TimeLimit as exc:
        print(f"mrta: {args.bids}: {exc}", file=sys.stderr)
        return 1
    except InputError as exc:            # the method cannot take this problem
        raise InputError(f"{args.bids}: {exc}") from None
    if args.json:
        print(json.dumps(result.to_json()))
        return 0
    print(f"value {result.value:g}  method {result.method}  nodes {result.nodes}  "
          f"seconds {result.seconds:.6f}" + ("  CAPPED (not proven optimal)" if result.capped else ""))
    for task in problem.tasks:
        if task in result.assignment:
            print(f"task {task}: robots {' '.join(str(r) for r in result.assignment[task])}")
    idle = [t for t in problem.tasks if t not in result.assignment]
    if idle:
        print(f"unassigned tasks: {' '.join(str(t) for t in idle)}")
    return 0
