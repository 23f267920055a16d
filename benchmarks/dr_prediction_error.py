"""How far the shipped interference model's prediction is from what the foraging world did: for every task a
dr-table run finished, its time from appearing to done against eq. 2 at its mean group (eq. 4 less the model's
I), per strategy, then over every strategy by group size (with eq. 4's ideal time and how far the group's largest
size was above its mean).  Above 1 the world was slower than the model says.

    python benchmarks/dr_prediction_error.py results/dr-table3/dr_table3_objects.csv [--area 1.0] [--model PATH]

Robots as the experiments run them: 2 wu per trip, 0.25 m/s, 0.12 s per wu (the calibration's).
"""
from __future__ import annotations

import argparse
import csv
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runtime.allocation.dr import model as M  # noqa: E402
from runtime.allocation.dr.interference import InterferenceModel  # noqa: E402
from sitl.experiments import dr_common as D  # noqa: E402
from sitl.experiments.dr_calibration import work_capacity  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("objects_csv")
    ap.add_argument("--area", type=float, default=D.Setup.delivery_area,
                    help="the delivery area's radius, m (distances run to its edge)")
    ap.add_argument("--model", default=str(D.shipped_model()))
    args = ap.parse_args()
    try:
        model = InterferenceModel.load(args.model)
        with open(args.objects_csv, newline="") as f:
            rows = [r for r in csv.DictReader(f) if r["done"] == "True"]
    except (OSError, ValueError, KeyError) as e:
        print(f"{args.objects_csv} / {args.model}: expected a dr-table objects CSV and a model file ({e})",
              file=sys.stderr)
        return 2
    tasks = []                                   # (cell, mean group, elapsed / predicted, elapsed / ideal, max - mean)
    for r in rows:
        n, d, weight = float(r["mean_group"]), max(0.0, float(r["d_m"]) - args.area), float(r["weight_wu"])
        ideal = n * work_capacity(d)
        predicted = M.expected_time(weight, M.group_capacity(ideal, model.predict(n, d)))
        if math.isfinite(predicted) and predicted > 0:
            elapsed = float(r["elapsed_s"])
            tasks.append((r["cell"], n, elapsed / predicted, elapsed / M.expected_time(weight, ideal),
                          float(r["max_group"]) - n))
    print("cell                      tasks  elapsed / predicted: p25  median   p75")
    for cell in dict.fromkeys(t[0] for t in tasks):
        ratio = [t[2] for t in tasks if t[0] == cell]
        p25, p50, p75 = np.percentile(ratio, [25, 50, 75])
        print(f"{cell:24s}  {len(ratio):5d}  {p25:24.2f}  {p50:6.2f}  {p75:5.2f}")
    print("\nevery cell, by mean group (rounded; 5 = 5 or more): medians")
    print("group  tasks  elapsed/predicted  elapsed/eq.4 ideal  max group - mean group")
    for g in sorted({min(round(t[1]), 5) for t in tasks}):
        sel = np.array([t[2:] for t in tasks if min(round(t[1]), 5) == g])
        print(f"{g:5d}  {len(sel):5d}  {np.median(sel[:, 0]):17.2f}  {np.median(sel[:, 1]):18.2f}  "
              f"{np.median(sel[:, 2]):22.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
