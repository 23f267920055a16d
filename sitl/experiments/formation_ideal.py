"""Paper 002 Fig. 6 and 7: mean and max % error vs the Hungarian optimum, 2..20 robots (= tasks).

Robots and tasks uniform in a 1000 x 1000 m field, straight-line costs, ``--cases`` instances per size
(paper: 100), BS, RTMA and the epsilon auction run as agents on the in-memory bus (lossless, 10 ms).
The figures themselves are lost from the paper's text; the numbers its prose gives sit beside ours.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from sitl.experiments import report
from sitl.experiments import formation_common as fc

# paper 002 Section IV-A prose (Figs. 6 and 7)
PAPER_RTMA_MEAN_AT_20 = 5.98
PAPER_MEAN_OF_MAX = {"rtma": 14.91, "bs": 33.77}
PAPER_BOTH_BELOW_UP_TO_8 = 10.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    fc.add_sweep_arguments(parser, cases=100, max_robots=20)


def claims(rows: list[dict], methods) -> list[tuple[str, str, str, bool | None]]:
    """The paper's statements about Figs. 6/7, each beside what this run measured."""
    sizes = sorted({r["robots"] for r in rows})
    get = {(r["robots"], r["method"]): r for r in rows}
    out = []
    have = set(methods)
    if "rtma" in have and 20 in sizes:
        v = get[(20, "rtma")]["mean_error_pct"]
        out.append(("RTMA mean error at 20 robots (Fig. 6; the prose calls it the maximum of that curve)",
                    f"{PAPER_RTMA_MEAN_AT_20:.2f} %", f"{v:.2f} %", None))
    if {"bs", "rtma"} <= have and sizes == list(range(2, 21)):
        for m in ("rtma", "bs"):
            out.append((f"{fc.LABELS[m]}: mean over sizes 2..20 of the max error (Fig. 7)",
                        f"{PAPER_MEAN_OF_MAX[m]:.2f} %", f"{fc.mean_of_max(rows, m):.2f} %", None))
    small = [n for n in sizes if n <= 8]
    for m in ("bs", "rtma"):
        if m in have and small:
            worst = max(get[(n, m)]["mean_error_pct"] for n in small)
            out.append((f"{fc.LABELS[m]}: mean error below 10 % up to 8 robots",
                        "< 10 %", f"max {worst:.2f} %", worst < PAPER_BOTH_BELOW_UP_TO_8))
    if "rtma" in have and 2 in sizes:
        r = get[(2, "rtma")]
        out.append(("RTMA always optimal with 2 robots", "0 % in every case",
                    f"{r['optimal_cases']}/{r['cases'] - r['not_converged']} optimal, max {r['max_error_pct']:.2g} %",
                    r["max_error_pct"] < 1e-9))
    if {"bs", "rtma"} <= have:
        worse = [n for n in sizes if get[(n, "rtma")]["mean_error_pct"] > get[(n, "bs")]["mean_error_pct"]]
        out.append(("RTMA better than BS (mean error)", "at every size",
                    "at every size" if not worse else f"worse at n = {', '.join(map(str, worse))}", not worse))
        if len(sizes) >= 3:
            slope = {m: float(np.polyfit(sizes, fc.by_method(rows, m, "mean_error_pct"), 1)[0]) for m in ("bs", "rtma")}
            out.append(("mean error roughly linear in n, RTMA with the lowest slope", "RTMA slope < BS slope",
                        f"RTMA {slope['rtma']:.2f} %/robot, BS {slope['bs']:.2f} %/robot",
                        slope["rtma"] < slope["bs"]))
    if "auction" in have:
        worst = max(get[(n, "auction")]["max_error_pct"] for n in sizes)
        out.append(("(not in the paper) epsilon auction max error", "-", f"{worst:.2g} %", None))
    return out


def run(args: argparse.Namespace) -> int:
    sizes = fc.sweep_sizes(args)
    methods = fc.parse_names(args.methods, "--methods", fc.METHODS)
    out = Path(args.out)
    t0 = time.perf_counter()
    rows = fc.error_sweep(fc.uniform_instance, sizes, args.cases, args.seed, methods, label="uniform")
    wall = time.perf_counter() - t0
    csv_path = report.write_csv(out / "formation_ideal.csv", rows)
    cmd = (f"mrta experiment formation-ideal --cases {args.cases} --min-robots {args.min_robots} "
           f"--max-robots {args.max_robots} --methods {','.join(methods)} --seed {args.seed}")
    setup = (f"Robots and tasks uniform in a {fc.FIELD_M:.0f} x {fc.FIELD_M:.0f} m field (Fig. 8 left), "
             f"straight-line costs, {args.cases} random instances per size, sizes {sizes[0]}..{sizes[-1]}, "
             f"seed {args.seed} (instances of size n from numpy default_rng(seed * 1000 + n)). Each method runs as "
             "sans-IO agents on the in-memory bus (10 ms delay, lossless); error = 100 (cost - optimum) / optimum "
             "against the Hungarian optimum (scipy). Messages: messages agents sent (a broadcast counts once), "
             f"mean per instance. Command: `{cmd}`. Wall time {wall:.1f} s.")
    sections = [("Setup", setup),
                ("Paper's statements (Section IV-A) beside ours", fc.claims_table(claims(rows, methods))),
                ("Fig. 6 and 7: error vs robots", fc.error_table(rows, methods))]
    nc = sum(r["not_converged"] for r in rows)
    if nc:
        sections.append(("Runs that did not converge", f"{nc} runs did not converge within 3600 s of sim time; "
                         "they are left out of the means."))
    md_path = report.write_markdown(out / "formation_ideal.md",
                                    "Paper 002 Fig. 6/7: BS, RTMA and the auction vs the Hungarian optimum", sections)
    written = [csv_path, md_path]
    if not args.no_png:
        paper = []
        if "rtma" in methods:
            paper.append(("mean", "paper RTMA, n=20", 20, PAPER_RTMA_MEAN_AT_20))
        paper += [("max", f"paper: {fc.LABELS[m]} mean of max {v} %", None, v)
                  for m, v in PAPER_MEAN_OF_MAX.items() if m in methods]
        written.append(fc.error_figure([("", rows, "-o")], out / "formation_ideal.png",
                                       f"Paper 002 Fig. 6/7 reproduced: {args.cases} cases per size, 1000 m field",
                                       paper if sizes[-1] >= 20 else ()))
    print("wrote " + ", ".join(map(str, written)))
    return 0 if nc == 0 else 1
