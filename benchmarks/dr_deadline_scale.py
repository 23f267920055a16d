"""The deadline at which Greedy meets as many deadlines in our foraging world as it does in the paper's (Table 3:
30.87 % of tasks within DL): Greedy ignores deadlines (every bidder is awarded, no eq. 8), so its finish times
measure the world alone, and the share of them within a deadline fixes that deadline's place on the world's
time scale.  Reads a dr-table3 run's objects CSV and prints Greedy's finish times and that deadline.

    python benchmarks/dr_deadline_scale.py results/dr-table3/dr_table3_objects.csv [--share 30.87]
"""
from __future__ import annotations

import argparse
import csv
import sys

from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sitl.experiments import dr_common as D  # noqa: E402
from sitl.experiments.dr_table3 import PAPER  # noqa: E402

PAPER_GREEDY_WITHIN_DL = PAPER["Greedy"][0]          # % (Table 3)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("objects_csv")
    ap.add_argument("--share", type=float, default=PAPER_GREEDY_WITHIN_DL, help="%% of Greedy's tasks within DL")
    args = ap.parse_args()
    try:
        with open(args.objects_csv, newline="") as f:
            rows = [r for r in csv.DictReader(f) if r["cell"] == "Greedy" and r["done"] == "True"]
    except (OSError, KeyError) as e:
        print(f"{args.objects_csv}: expected a dr-table3 objects CSV ({e})", file=sys.stderr)
        return 2
    if not rows:
        print(f"{args.objects_csv}: no finished Greedy task in it", file=sys.stderr)
        return 2
    t = np.array([float(r["elapsed_s"]) for r in rows])
    q = [10, 25, 50, 75, 90]
    print(f"Greedy: {len(t)} tasks done over {len({r['seed'] for r in rows})} seeds; finish time (s from appearing) "
          + ", ".join(f"p{p} {v:.0f}" for p, v in zip(q, np.percentile(t, q))))
    dl = float(np.percentile(t, args.share))
    print(f"deadline with {args.share:g} % of Greedy's tasks within it: {dl:.0f} s "
          f"({dl / D.DL:.2f} x the paper's 900 tu = {D.DL:g} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
