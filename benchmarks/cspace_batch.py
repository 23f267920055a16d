"""CoMutaR's constraint functions for a fleet of 16 (runtime/control/cspace.py): one batched call against one call
per robot, measured in the same run (the batch is why a fleet's cycle stays in milliseconds; the test
tests/test_comutar_cspace.py holds the two to the same choices).

    PYTHONPATH=. python benchmarks/cspace_batch.py [--repeats N]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from runtime.control import cspace as C


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=50)
    args = ap.parse_args()
    win = C.Window()
    rng = np.random.default_rng(0)
    poses = np.column_stack([rng.uniform(-8, 8, (16, 2)), rng.uniform(-3, 3, 16)])
    obstacles = np.column_stack([poses[:, :2], np.full(16, 0.25)])
    ignore, goals = np.eye(16, dtype=bool), rng.uniform(-8, 8, (16, 2))

    def batch():
        C.choose(win, [C.survey(win, poses, goals), C.avoid(win, poses, obstacles, 0.25, ignore)], 16)

    def each():
        for i in range(16):
            C.choose(win, [C.survey(win, poses[i:i + 1], goals[i:i + 1]),
                           C.avoid(win, poses[i:i + 1], obstacles, 0.25, ignore[i:i + 1])], 1)

    out = {}
    for name, fn in (("one batch of 16", batch), ("16 calls of 1", each)):
        fn()
        best = float("inf")
        for _ in range(5):
            t0 = time.process_time()
            for _ in range(args.repeats):
                fn()
            best = min(best, (time.process_time() - t0) / args.repeats)
        out[name] = best
        print(f"{name:<16} {best * 1e3:7.2f} ms of CPU per fleet evaluation (best of 5 x {args.repeats})")
    print(f"ratio: the batch costs {out['one batch of 16'] / out['16 calls of 1']:.2f} of one call per robot")


if __name__ == "__main__":
    main()
