"""How far the shipped interference model's prediction is from what the foraging world did: for every task a
dr-table run finished, its time from appearing to done against eq. 2 at its mean group (eq. 4 less the model's
I), per strategy.  Above 1 the world was slower than the model says.

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
from sitl.experiments.dr_calibration import LOAD, LOAD_TIME, SPEED  # noqa: E402


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
    print("cell                      tasks  elapsed / predicted: p25  median   p75")
    for cell in dict.fromkeys(r["cell"] for r in rows):
        ratio = []
        for r in (r for r in rows if r["cell"] == cell):
            n, d = float(r["mean_group"]), max(0.0, float(r["d_m"]) - args.area)
            cap = M.group_capacity(n * M.work_capacity(LOAD, SPEED, d, LOAD_TIME), model.predict(n, d))
            predicted = M.expected_time(float(r["weight_wu"]), cap)
            if math.isfinite(predicted) and predicted > 0:
                ratio.append(float(r["elapsed_s"]) / predicted)
        if ratio:
            p25, p50, p75 = np.percentile(ratio, [25, 50, 75])
            print(f"{cell:24s}  {len(ratio):5d}  {p25:24.2f}  {p50:6.2f}  {p75:5.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
