"""Is the interference model wrong, or is a task's mean group the wrong thing to predict with?  Runs Table 3's
setting (10 robots, 3 objects of 40 wu, deadline 328 s, the shipped model, off-line) for a few cells and seeds,
keeps each finished task's group over time (robots committed, at every change), and compares the task's weight
with the work the model says that group would have done over the task's life: the sum over the group's spans of
max(0, n x eq. 5 - I(n, d)) x span (eqs. 3-4).  Below 1 the world moved less than the model says at the sizes the group
really had (the model is optimistic); 1 is a perfect model.

    PYTHONPATH=. python benchmarks/dr_group_timeline.py [--seconds 1200] [--seeds 1,2] [--cells NM_I,M_I,Greedy,NM_NI]

Printed per cell and then by how the group changed: tasks whose group stayed about the same size (largest size
less than half a robot above the time-averaged one) against tasks whose group grew late, and by largest size.
"""
from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runtime.allocation.dr import model as M  # noqa: E402
from runtime.allocation.dr.interference import InterferenceModel  # noqa: E402
from sitl.experiments import dr_common as D  # noqa: E402
from sitl.experiments import dr_table3 as T3  # noqa: E402
from sitl.experiments.dr_calibration import work_capacity  # noqa: E402


def tasks_of(label: str, seed: int, setup: D.Setup) -> list[dict]:
    """Every finished task of one run: distance to D's edge, weight, life span and group timeline."""
    from sitl.foraging import harness

    cell = next(c for c in T3.CELLS if c.label == label)
    fr = harness.ForagingRun(D.config(cell, setup, seed, D.shipped_model()))
    try:
        fr.run()
        return [{"d": max(0.0, math.hypot(o.x, o.y) - setup.delivery_area), "weight": o.weight,
                 "appeared": o.appeared, "finished": o.finished, "coalition": list(o.coalition),
                 "mean": o.mean_coalition(o.finished)}
                for o in fr.objects.values() if o.finished is not None]
    finally:
        fr.close()


def spans(task: dict):
    """(robots, seconds) of each span of the task's life with a constant group."""
    marks = task["coalition"] + [(task["finished"], 0)]
    for (t, n), (t2, _) in zip(marks, marks[1:]):
        a, b = max(t, task["appeared"]), min(t2, task["finished"])
        if b > a:
            yield n, b - a


def measure(task: dict, model: InterferenceModel) -> tuple[float, float, float]:
    """(weight / work the model predicts over the group's timeline, mean group, largest group)."""
    d, work, largest = task["d"], 0.0, 0
    for n, dt in spans(task):
        if n > 0:
            work += max(0.0, M.group_capacity(n * work_capacity(d), model.predict(n, d))) * dt
        largest = max(largest, n)
    return (task["weight"] / work if work > 0 else math.inf), task["mean"], largest


def quartiles(x) -> str:
    q = np.percentile(x, [25, 50, 75])
    return f"{q[0]:.2f} {q[1]:.2f} {q[2]:.2f}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=1200.0, help="simulated s per run (default 1200)")
    ap.add_argument("--seeds", default="1,2", help="comma-separated seeds (default 1,2)")
    ap.add_argument("--cells", default="NM_I,M_I,Greedy,NM_NI", help="Table 3 cells (default NM_I,M_I,Greedy,NM_NI)")
    args = ap.parse_args()
    labels = {c.label for c in T3.CELLS}
    try:
        seeds = [int(s) for s in args.seeds.split(",")]
        cells = args.cells.split(",")
        if not set(cells) <= labels or not seeds:
            raise ValueError
    except ValueError:
        print(f"--seeds {args.seeds!r} / --cells {args.cells!r}: expected integers and cells among {sorted(labels)}",
              file=sys.stderr)
        return 2
    setup = replace(T3.SETUP, deadline=328.0, time_limit=args.seconds)
    model = InterferenceModel.load(D.shipped_model())
    rows = []                                       # (cell, weight / predicted work, mean group, largest group)
    for label in cells:
        for seed in seeds:
            found = [(label, *measure(t, model)) for t in tasks_of(label, seed, setup)]
            rows += found
            print(f"  {label} seed {seed}: {len(found)} tasks", file=sys.stderr, flush=True)
    print(f"Table 3's setting, deadline 328 s, {args.seconds:g} s runs, seeds {args.seeds}; weight / work the model "
          f"predicts over the group's real timeline (below 1: the world moved less than the model says)")
    print("cell      tasks  p25 median p75   mean group  largest group")
    for label in cells:
        a = np.array([r[1:] for r in rows if r[0] == label])
        if len(a):
            print(f"{label:8s} {len(a):5d}   {quartiles(a[:, 0])}   {a[:, 1].mean():10.2f}  {a[:, 2].mean():13.2f}")
    if not rows:
        print("no task finished: run longer (--seconds)")
        return 1
    a = np.array([r[1:] for r in rows])
    grew = a[:, 2] - a[:, 1] >= 0.5
    for name, sel in (("group about steady (largest - mean < 0.5)", ~grew), ("group grew (largest - mean >= 0.5)", grew)):
        if sel.any():
            print(f"{name}: {sel.sum()} tasks, {quartiles(a[sel, 0])}, mean group {a[sel, 1].mean():.2f}")
    for g in sorted({int(x) for x in a[:, 2]}):
        sel = a[:, 2] == g
        print(f"largest group {g}: {sel.sum():3d} tasks, {quartiles(a[sel, 0])}, mean group {a[sel, 1].mean():.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
