"""What does DR's auction for a robot (Alg. 3) decide that SR's first-award rule does not?  Runs Table 4's setting
(10 robots, 3 objects of 40 wu at a time, utilities 50-150, deadline 328 s, soft, the shipped model, off-line) for
DR and SR cells and seeds, and counts, on every robot:

* DR: each Alg. 3 window (``time_bid_accepted`` s of collecting awards): how many awards it held when it closed,
  whether the robot joined the award that came first (what SR would have joined), and if not, how much more
  utility the award it chose carried than the first one;
* SR: each award that reached a robot no longer free because it had joined another task's group moments before
  (an award DR would have weighed against the one taken, had both come within the window).

If DR's choice rarely differs from the first award, DR and SR make the same groups and differ by noise.

    PYTHONPATH=. python benchmarks/dr_robot_auction.py [--seconds 1200] [--seeds 1,2] [--strategies NM_I,M_I]
"""
from __future__ import annotations

import argparse
import sys
from collections import Counter, defaultdict
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runtime.allocation.dr import family as F  # noqa: E402
from runtime.allocation.dr.options import DrOptions  # noqa: E402
from sitl.experiments import dr_common as D  # noqa: E402
from sitl.experiments import dr_table4 as T4  # noqa: E402

COUNTS: Counter = Counter()
GAINS: list = []
SIZES: Counter = Counter()


def _instrument() -> None:
    """Wrap the agent's Alg. 3 close and its award handler (the benchmark's process only)."""
    close, on_award = F.DrAgent._offers_tick, F.DrAgent._on_award

    def offers_tick(self, now):
        if self.offers and now >= self.offers.until:
            held = list(self.offers.by_leader.values())        # arrival order: the first award is held[0]
            out = close(self, now)
            ms = self.membership
            chosen = next((o for o in held if ms is not None and ms.leader == o.leader and ms.task == o.task), None)
            SIZES[len(held)] += 1
            COUNTS["windows"] += 1
            if chosen is None:
                COUNTS["joined none"] += 1
            elif chosen is held[0]:
                COUNTS["joined the first"] += 1
            else:
                COUNTS["joined another"] += 1
                GAINS.append(chosen.value - held[0].value)
            return out
        return close(self, now)

    def award(self, m, now):
        if self.o.auction == "sr":
            ms = self.membership
            busy = ms is not None and not (ms.task == m.task and ms.leader == m.sender)
            COUNTS["sr awards"] += 1
            if busy and now - ms.joined <= self.o.time_bid_accepted:
                COUNTS["sr award within the window after joining"] += 1
        return on_award(self, m, now)

    F.DrAgent._offers_tick, F.DrAgent._on_award = offers_tick, award
    award_type = next(t for t, h in F._HANDLERS.items() if h is on_award)
    F._HANDLERS[award_type] = award                         # dispatch looks handlers up in this table


def run(cell: D.Cell, seed: int, setup: D.Setup) -> int:
    from sitl.foraging import harness

    fr = harness.ForagingRun(D.config(cell, setup, seed, D.shipped_model()))
    try:
        fr.run()
        return sum(o.finished is not None for o in fr.objects.values())
    finally:
        fr.close()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=1200.0, help="simulated s per run (default 1200)")
    ap.add_argument("--seeds", default="1,2", help="comma-separated seeds (default 1,2)")
    ap.add_argument("--strategies", default="NM_I,M_I", help="strategies (default NM_I,M_I)")
    args = ap.parse_args()
    cells = {c.label: c for c in T4.CELLS}
    try:
        seeds = [int(s) for s in args.seeds.split(",")]
        wanted = [(f"DR {s} soft", f"SR {s}") for s in args.strategies.split(",")]
        if not seeds or any(a not in cells or b not in cells for a, b in wanted):
            raise ValueError
    except ValueError:
        print(f"--seeds {args.seeds!r} / --strategies {args.strategies!r}: expected integers and strategies among "
              "NM_NI,NM_I,M_NI,M_I", file=sys.stderr)
        return 2
    setup = replace(T4.SETUP, deadline=328.0, time_limit=args.seconds, max_objects=None)
    _instrument()
    per: dict = defaultdict(Counter)
    for pair in wanted:
        for label in pair:
            for seed in seeds:
                before, sizes_before, gains_before = Counter(COUNTS), Counter(SIZES), len(GAINS)
                done = run(cells[label], seed, setup)
                per[label].update(COUNTS - before)
                per[label]["tasks done"] += done
                per[label]["2+ awards"] += sum((SIZES - sizes_before)[k] for k in SIZES if k >= 2)
                per[label]["gain"] += sum(GAINS[gains_before:])
                print(f"  {label} seed {seed}: {done} tasks done", file=sys.stderr, flush=True)
    print(f"Table 4's setting (soft, deadline 328 s), {args.seconds:g} s runs, seeds {args.seeds}")
    for label, c in per.items():
        if label.startswith("DR"):
            w = c["windows"] or 1
            print(f"{label}: {c['tasks done']} tasks done; {c['windows']} Alg. 3 windows, {c['2+ awards']} with 2+ awards "
                  f"({100 * c['2+ awards'] / w:.1f} %); joined the first award {c['joined the first']}, another "
                  f"{c['joined another']} ({100 * c['joined another'] / w:.1f} %, mean utility gained "
                  f"{c['gain'] / max(c['joined another'], 1):.1f}), none {c['joined none']}")
        else:
            print(f"{label}: {c['tasks done']} tasks done; {c['sr awards']} awards received, "
                  f"{c['sr award within the window after joining']} within {DrOptions().time_bid_accepted:g} s after joining another group")
    return 0


if __name__ == "__main__":
    sys.exit(main())
