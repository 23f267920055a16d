"""What compiling the arbiter's costliest kernel would buy: ``AvoidObstacles.time_to_collision`` as shipped (numpy)
beside the same computation as one compiled loop (numba, which is not a dependency of the runtime: ``pip install
numba`` to run this), on the calls a foraging run makes.

Records every time-to-collision call of a ``--seconds`` dr run (10 robots, 3 objects, seed 1), checks that the
compiled kernel returns the same array bit for bit on every call, then times both on the recorded calls in
alternating blocks (so that a busy machine slows both alike) and prints microseconds per call and the ratio, and
what share of the run's executive time that call is.  The answer to "would compiled kernels reach 120x real
time": see docs/foraging.md#speed.

    PYTHONPATH=. python benchmarks/ttc_compiled.py [--seconds 60]
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runtime.control import behaviours as A  # noqa: E402
from runtime.control import compiled as _shipped  # noqa: E402

_shipped.AVAILABLE = _shipped.ENABLED = False   # "shipped" below is the numpy code, not runtime/control/compiled.py

try:
    from numba import njit, uint64
except ImportError:                         # pragma: no cover - the message is the point
    njit = None


def compiled():
    """The compiled kernel: per (turn rate, step) row and point the interval of speeds hit (as the numpy code's),
    a bitmask of the speeds hit per row, and the first step whose mask holds a speed."""
    @njit(cache=False, nogil=True)
    def ttc(pts, rays, g, speeds, first, nw, steps, clearance, reach):
        nv = speeds.shape[0]
        out = np.full(nv * nw, np.inf)
        n = pts.shape[0]
        px, py, lim = np.empty(n), np.empty(n), np.empty(n)
        k, rr, c2, one = 0, reach + clearance, clearance * clearance, uint64(1)
        for j in range(n):
            d2 = pts[j, 0] * pts[j, 0] + pts[j, 1] * pts[j, 1]
            if d2 <= rr * rr:
                px[k], py[k], lim[k] = pts[j, 0], pts[j, 1], min(c2 - d2, -1e-12)
                k += 1
        if k == 0:
            return out
        for i in range(nw):
            seen = uint64(0)
            for t in range(steps):
                r = i * steps + t
                row = uint64(0)
                for q in range(k):
                    a = rays[r, 0] * px[q] + rays[r, 1] * py[q]
                    m = a * a + lim[q]
                    if m >= 0:
                        root = math.sqrt(m)
                        x0, x1 = (a - root) / g[r], (a + root) / g[r]
                        lo = 0
                        while lo < nv and speeds[lo] < x0:
                            lo += 1
                        hi = lo
                        while hi < nv and speeds[hi] <= x1:
                            hi += 1
                        for s in range(lo, hi):
                            row |= one << uint64(s)
                new = row & ~seen
                if new:
                    seen |= new
                    for s in range(nv):
                        if (new >> uint64(s)) & one:
                            out[s * nw + i] = first[steps - t]
        return out
    return ttc


def record(seconds: float) -> tuple[list, dict]:
    """The time-to-collision calls of one dr run (points, arc set, horizon, steps, clearance, result) and its
    timing split."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import foraging_speed as F
    from sitl.foraging.harness import ForagingConfig

    calls = []
    shipped = A.AvoidObstacles.time_to_collision

    def spy(self, arcs, horizon, steps=16):
        out = shipped(self, arcs, horizon, steps)
        calls.append((self._points.copy(), arcs, float(horizon), int(steps), self.radius + self.margin, out))
        return out

    method, options = F.method_of("dr")
    A.AvoidObstacles.time_to_collision = spy
    try:
        timing, _, _, _ = F.measure(ForagingConfig(robots=10, method=method, options=options, seed=1,
                                                   time_limit=seconds))
    finally:
        A.AvoidObstacles.time_to_collision = shipped
    return calls, timing


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="simulated s of the recorded run (default 60)")
    ap.add_argument("--blocks", type=int, default=6, help="alternating timing blocks of each (default 6)")
    args = ap.parse_args()
    if njit is None:
        print("numba is not installed (it is not a runtime dependency): pip install numba", file=sys.stderr)
        return 2
    calls, timing = record(args.seconds)
    ttc = compiled()
    avoid = A.AvoidObstacles()

    def shipped_all():
        for pts, arcs, horizon, steps, _, _ in calls:
            avoid._points = pts
            avoid.time_to_collision(arcs, horizon, steps)

    def compiled_all():
        for pts, arcs, horizon, steps, clearance, _ in calls:
            k = A._arc_rays(arcs, horizon, steps)
            ttc(pts, k.rays, k.g, k.speeds, k.first, k.nw, k.steps, clearance, k.reach)

    same = 0
    for pts, arcs, horizon, steps, clearance, out in calls:
        k = A._arc_rays(arcs, horizon, steps)
        same += np.array_equal(ttc(pts, k.rays, k.g, k.speeds, k.first, k.nw, k.steps, clearance, k.reach), out)
    spent = {"numpy": 0.0, "compiled": 0.0}
    for _ in range(args.blocks):
        for name, fn in (("numpy", shipped_all), ("compiled", compiled_all)):
            t0 = time.perf_counter()
            fn()
            spent[name] += time.perf_counter() - t0
    n = len(calls) * args.blocks
    us = {name: 1e6 * s / n for name, s in spent.items()}
    pts = np.mean([len(c[0]) for c in calls])
    share = spent["numpy"] / args.blocks / max(timing["executive"], 1e-9)
    print(f"{len(calls)} calls recorded from a {args.seconds:g} s dr run (10 robots, seed 1; {pts:.1f} range points "
          f"per call); compiled result identical on {same} of {len(calls)}")
    print(f"time to collision: numpy {us['numpy']:.1f} us per call, compiled (numba) {us['compiled']:.1f} us: "
          f"{us['numpy'] / us['compiled']:.1f}x")
    print(f"the numpy calls take {100 * share:.0f} % of the run's executive time ({timing['executive']:.1f} s); "
          f"compiled, the executive would take {100 * (1 - share * (1 - us['compiled'] / us['numpy'])):.0f} % of it")
    return 0 if same == len(calls) else 1


if __name__ == "__main__":
    sys.exit(main())
