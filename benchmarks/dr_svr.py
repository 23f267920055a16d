"""Paper 000's interference model on a robot: the on-line refit (every robot keeps the newest 120 samples and
refits after each finished task) and a prediction (a leader predicts I(n, d) for every group size it weighs),
beside the same work done the naive way, all measured in this run:

* refit: ``InterferenceModel.add`` at a full window of 120 samples (a batch refit with the C and gamma chosen
  off-line) beside a refit that grid-searches C and gamma again by cross-validation (what a robot would do without
  the off-line choice);
* predict: one ``predict(n, d)`` beside scikit-learn's ``SVR.predict`` on the same fitted model (ours adds the
  input scaling and the target's inverse standardisation).

The paper's robots had a 600 MHz CPU: a refit must take milliseconds. Samples: the shipped calibration's 80 plus
40 jittered copies (120).

    PYTHONPATH=. python benchmarks/dr_svr.py [--repeat 20]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runtime.allocation.dr.interference import InterferenceModel  # noqa: E402

SHIPPED = ROOT / "runtime" / "allocation" / "dr" / "interference_pioneer3dx.json"


def best(fn, repeat: int) -> float:
    """The fastest of ``repeat`` timings of ``fn()`` (s): the least disturbed by the machine's other work."""
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return min(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=20)
    args = ap.parse_args()
    shipped = InterferenceModel.load(SHIPPED)
    rng = np.random.default_rng(1)
    base = list(shipped.samples)
    extra = [(n, d, i * (1 + 0.05 * rng.standard_normal())) for n, d, i in (base[k % len(base)] for k in range(40))]
    window = (base + extra)[-120:]
    model = shipped.copy()
    model.fit(window, search=False)
    print(f"{len(window)} samples, C {model.C:g}, gamma {model.gamma:g} (chosen off-line)")

    def refit():
        model.add(*window[len(model.samples) % len(window)])          # window full: drop the oldest, refit

    def research():
        InterferenceModel.from_samples(window, search=True)

    t_add = best(refit, args.repeat)
    t_search = best(research, max(1, args.repeat // 10))
    print(f"refit at 120 samples:   ours {t_add * 1e3:8.2f} ms   with a new grid search {t_search * 1e3:8.1f} ms   "
          f"ratio {t_search / t_add:.0f}")
    svr, x = model._svr, np.array([[4.0, 1.4]])
    lo, span, _, _ = model._scale

    def ours():
        model.predict(4, 1.4)

    def raw():
        svr.predict((x - lo) / span)

    n = 200
    t_ours = best(lambda: [ours() for _ in range(n)], args.repeat) / n
    t_raw = best(lambda: [raw() for _ in range(n)], args.repeat) / n
    print(f"predict one I(n, d):    ours {t_ours * 1e6:8.1f} us   scikit-learn SVR.predict {t_raw * 1e6:8.1f} us   "
          f"ratio {t_ours / t_raw:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
