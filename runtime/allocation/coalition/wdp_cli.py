"""`mrta wdp BIDS.json`: pick the winning coalition bids of one simultaneous allocation round."""
from __future__ import annotations

import argparse
import json

from runtime.allocation.coalition import winner_determination as wd
from runtime.errors import InputError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("wdp", help="winner determination for coalition bids (paper 001)",
                       description="Choose the bids with the largest total value such that no robot is in "
                                   "two winning coalitions and no task is won twice.")
    p.add_argument("bids", metavar="BIDS.json",
                   help='{"robots": [ids], "tasks": [ids], "bids": [{"task", "robots", "value"}]} ("-" = stdin)')
    p.add_argument("--method", default="auto", choices=wd.METHODS, help="solver (default: %(default)s)")
    p.add_argument("--node-limit", type=int, default=None,
                   help="stop IDA*/BFS after this many nodes (answer then marked capped)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.node_limit is not None and args.node_limit < 1:
        raise InputError(f"--node-limit {args.node_limit}: expected a positive number of nodes")
    problem = wd.load_problem(args.bids)
    result = wd.solve(problem, args.method, node_limit=args.node_limit)
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
