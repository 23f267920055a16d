"""Paper 002 Fig. 9: the error sweep on the two-box distribution of Fig. 8 (right).

The figure is lost from the paper's text; the prose says "most of the formation points and the initial
positions of the robots calculated at random in the small box and the others calculated outside the
big box and calculated also at random".  Reconstruction (options): a ``--small-box`` square and a
``--big-box`` square, both centred in the 1000 x 1000 m field; robots and tasks each, independently,
``round(--inside * n)`` (at least a majority, at most n - 1) uniform in the small box and the rest
uniform in the field outside the big box.  The same sizes and seed also run on the uniform distribution
(BS and RTMA) so that the paper's comparison with Fig. 6 is made within one run.
"""
from __future__ import annotations

import argparse
import functools
import statistics
import time
from pathlib import Path

import numpy as np

from runtime.errors import InputError
from sitl.experiments import report
from sitl.experiments import formation_common as fc


def add_arguments(parser: argparse.ArgumentParser) -> None:
    fc.add_sweep_arguments(parser, cases=100, max_robots=20, repeats=200)
    parser.add_argument("--small-box", type=float, default=400.0, help="side of the centred small box (m)")
    parser.add_argument("--big-box", type=float, default=700.0, help="side of the centred big box (m)")
    parser.add_argument("--inside", type=float, default=0.75, help="share of robots and of tasks in the small box")
    parser.add_argument("--no-uniform", action="store_true", help="skip the uniform comparison sweep")
    parser.add_argument("--sensitivity-cases", type=int, default=200,
                        help="cases per size for the box-size sensitivity table, closed form (0: skip)")


SENSITIVITY_SMALL = (100.0, 200.0, 300.0, 400.0, 500.0)
SENSITIVITY_BIG = (600.0, 700.0, 800.0)


def instance_fn(args):
    small = fc.positive(args.small_box, "--small-box", fc.FIELD_M)
    big = fc.positive(args.big_box, "--big-box", fc.FIELD_M)
    if not small <= big < fc.FIELD_M:
        raise InputError(f"--small-box {small:g} --big-box {big:g}: expected small <= big < {fc.FIELD_M:g} m")
    inside = fc.positive(args.inside, "--inside", 1.0)
    if inside <= 0.5:
        raise InputError(f"--inside {inside:g}: expected a majority, in (0.5, 1]")

    return functools.partial(fc.twobox_instance, size=fc.FIELD_M, small=small, big=big, inside=inside)


def claims(rows: list[dict], uni: list[dict], methods) -> list[tuple[str, str, str, bool | None]]:
    """The paper's statements about Fig. 9 beside this run (uniform rows from the same run)."""
    sizes = sorted({r["robots"] for r in rows})
    get = {(r["robots"], r["method"]): r for r in rows}
    uget = {(r["robots"], r["method"]): r for r in uni}
    out = []
    if {"bs", "rtma"} <= set(methods):
        worse = [n for n in sizes if get[(n, "rtma")]["mean_error_pct"] > get[(n, "bs")]["mean_error_pct"]]
        out.append(("RTMA again better than BS (mean error, two-box)", "at every size",
                    "at every size" if not worse else f"worse at n = {', '.join(map(str, worse))}", not worse))
    if not uni:
        return out
    diff = {m: [get[(n, m)]["mean_error_pct"] - uget[(n, m)]["mean_error_pct"] for n in sizes]
            for m in ("bs", "rtma") if m in methods}
    if "rtma" in diff:
        d = diff["rtma"]
        out.append(("RTMA: two-box results similar to the uniform ones (Fig. 6)", "similar",
                    f"two-box - uniform mean error: {statistics.fmean(d):+.2f} points on average "
                    f"(range {min(d):+.2f} .. {max(d):+.2f})", None))
    if "bs" in diff:
        d = diff["bs"]
        out.append(("BS: worse on two-box than on uniform", "worse",
                    f"{statistics.fmean(d):+.2f} points on average, worse at {sum(x > 0 for x in d)}/{len(d)} sizes",
                    statistics.fmean(d) > 0))
        half = len(sizes) // 2
        if half >= 1:
            lo, hi = statistics.fmean(d[:half]), statistics.fmean(d[half:])
            out.append(("BS: ... especially for low numbers of robots", "gap larger at low n",
                        f"{lo:+.2f} points at n = {sizes[0]}..{sizes[half - 1]}, "
                        f"{hi:+.2f} at n = {sizes[half]}..{sizes[-1]}", lo > 0 and lo > hi))
    return out


def sensitivity(sizes, cases: int, seed: int, inside: float) -> list[dict]:
    """Closed-form BS and RTMA on two-box reconstructions with other box sizes: does each of the paper's
    Fig. 9 statements hold?  Same sizes and seed as the main run, ``cases`` instances per size."""
    uni = fc.sample_statistics(fc.closed_form_sweep(fc.uniform_instance, sizes, cases, 1, seed, ("bs", "rtma")))
    table = []
    for small in SENSITIVITY_SMALL:
        for big in SENSITIVITY_BIG:
            make = functools.partial(fc.twobox_instance, size=fc.FIELD_M, small=small, big=big, inside=inside)
            two = fc.sample_statistics(fc.closed_form_sweep(make, sizes, cases, 1, seed, ("bs", "rtma")))
            sizes_ = sorted({r["robots"] for r in two})
            get = {(r["robots"], r["method"]): r["mean_error_pct"] for r in two}
            uget = {(r["robots"], r["method"]): r["mean_error_pct"] for r in uni}
            d = {m: [get[(n, m)] - uget[(n, m)] for n in sizes_] for m in ("bs", "rtma")}
            half = max(1, len(sizes_) // 2)
            lo, hi = statistics.fmean(d["bs"][:half]), statistics.fmean(d["bs"][half:] or d["bs"])
            line = {"small box (m)": small, "big box (m)": big,
                    "RTMA two-box - uniform (points)": statistics.fmean(d["rtma"]),
                    "BS two-box - uniform (points)": statistics.fmean(d["bs"]),
                    "BS, low n": lo, "BS, high n": hi,
                    "RTMA < BS everywhere": "yes" if all(get[(n, "rtma")] <= get[(n, "bs")] for n in sizes_) else "no",
                    "BS worse, more at low n": "yes" if statistics.fmean(d["bs"]) > 0 and lo > 0 and lo > hi else "no"}
            table.append(line)
            fc.log.info("two-box sensitivity small %g big %g done", small, big)
    return table


def comparison_table(rows: list[dict], uni: list[dict]) -> str:
    table = []
    for n in sorted({r["robots"] for r in rows}):
        line: dict = {"robots": n}
        for m in ("bs", "rtma"):
            t = next((r for r in rows if r["robots"] == n and r["method"] == m), None)
            u = next((r for r in uni if r["robots"] == n and r["method"] == m), None)
            if t and u:
                line[f"{fc.LABELS[m]} two-box %"] = t["mean_error_pct"]
                line[f"{fc.LABELS[m]} uniform %"] = u["mean_error_pct"]
        table.append(line)
    return report.markdown_table(table, ["robots", "BS two-box %", "BS uniform %", "RTMA two-box %", "RTMA uniform %"])


def instance_figure(make, path: Path, n: int, seed: int, small: float, big: float) -> Path:
    """One instance drawn like Fig. 8 (right)."""
    robots, tasks = make(np.random.default_rng(seed), n)
    fig, ax = report.figure()
    from matplotlib.patches import Rectangle
    c = fc.FIELD_M / 2
    for side, style in ((small, "-"), (big, "--")):
        ax.add_patch(Rectangle((c - side / 2, c - side / 2), side, side, fill=False, ls=style, color="0.4"))
    ax.plot(robots[:, 0], robots[:, 1], "o", ms=4, label="robots")
    ax.plot(tasks[:, 0], tasks[:, 1], "x", ms=5, label="tasks")
    ax.set_xlim(0, fc.FIELD_M)
    ax.set_ylim(0, fc.FIELD_M)
    ax.set_aspect("equal")
    ax.legend(fontsize=7)
    ax.set_title(f"two-box instance, n = {n} (small box {small:g} m, big box {big:g} m)", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    import matplotlib.pyplot as plt
    plt.close(fig)
    return path


def run(args: argparse.Namespace) -> int:
    sizes = fc.sweep_sizes(args)
    methods = fc.parse_names(args.methods, "--methods", fc.METHODS)
    make = instance_fn(args)
    out = Path(args.out)
    t0 = time.perf_counter()
    if args.sensitivity_cases < 0:
        raise InputError(f"--sensitivity-cases {args.sensitivity_cases}: expected 0 or more")
    rows = fc.error_sweep(make, sizes, args.cases, args.seed, methods, label="twobox")
    uni_methods = tuple(m for m in ("bs", "rtma") if m in methods)
    uni = [] if args.no_uniform or not uni_methods else fc.error_sweep(
        fc.uniform_instance, sizes, args.cases, args.seed, uni_methods, label="uniform")
    cf_methods = [m for m in methods if m in fc.CLOSED_FORM]
    exp_two = fc.sample_statistics(fc.closed_form_sweep(make, sizes, args.cases, args.repeats, args.seed,
                                                        cf_methods, label="two-box"))
    exp_uni = fc.sample_statistics(fc.closed_form_sweep(fc.uniform_instance, sizes, args.cases, args.repeats,
                                                        args.seed, uni_methods, label="uniform")) if uni else []
    sens = sensitivity(sizes, args.sensitivity_cases, args.seed, args.inside) \
        if args.sensitivity_cases and {"bs", "rtma"} <= set(methods) else []
    wall = time.perf_counter() - t0
    csv_path = report.write_csv(out / "formation_twobox.csv", rows + uni)
    extra_csv = []
    if exp_two:
        extra_csv.append(report.write_csv(out / "formation_twobox_expected.csv",
                                          [{"distribution": "twobox", **r} for r in exp_two]
                                          + [{"distribution": "uniform", **r} for r in exp_uni]))
    cmd = (f"mrta experiment formation-twobox --cases {args.cases} --min-robots {args.min_robots} "
           f"--max-robots {args.max_robots} --methods {','.join(methods)} --seed {args.seed} "
           f"--small-box {args.small_box:g} --big-box {args.big_box:g} --inside {args.inside:g} "
           f"--repeats {args.repeats} --sensitivity-cases {args.sensitivity_cases}"
           + (" --no-uniform" if args.no_uniform else ""))
    counts = ", ".join(f"n={n}: {fc.inside_count(n, args.inside)} in" for n in (sizes[0], sizes[-1]))
    recon = (f"Fig. 8 (right) is lost from the text; the prose says most robots and formation points are drawn at "
             f"random in the small box and the others at random outside the big box. Reconstruction: in the "
             f"{fc.FIELD_M:.0f} x {fc.FIELD_M:.0f} m field, a {args.small_box:g} m small box and a {args.big_box:g} m "
             f"big box, both centred; robots and tasks are drawn independently, round({args.inside:g} n) of each "
             f"(at least a majority, at most n - 1, so n = 2 has one of each inside) uniform in the small box and "
             f"the rest uniform in the field outside the big box ({counts}). The sizes of the boxes and the share "
             f"inside are our choice (the text gives none); `formation_twobox_instance.png` shows one instance. "
             "Whether the paper's statements hold depends on these choices: see the sensitivity table, and the "
             "defaults (400 m and 700 m) are a reconstruction on which they hold.")
    setup = (f"{args.cases} instances per size, sizes {sizes[0]}..{sizes[-1]}, seed {args.seed}; straight-line costs; "
             "agents on the in-memory bus (10 ms, lossless); error vs the Hungarian optimum. The uniform rows use "
             f"the same sizes, cases and seed as `formation-ideal`. Command: `{cmd}`. Wall time {wall:.1f} s.")
    sections = [("Two-box distribution (our reconstruction)", recon), ("Setup", setup)]
    if exp_two:
        sections.append((f"Paper's statements (Section IV-A, Fig. 9) beside ours: expected, {args.repeats} x "
                         f"{args.cases} cases per size (closed form)",
                         fc.claims_table(claims(exp_two, exp_uni, methods))))
    sections += [(f"Paper's statements beside ours: the {args.cases} cases run as agents",
                  fc.claims_table(claims(rows, uni, methods))),
                 ("Fig. 9: error vs robots, two-box (agents)", fc.error_table(rows, methods))]
    if exp_two and exp_uni:
        sections.append(("Two-box vs uniform, expected mean error (closed form)", comparison_table(exp_two, exp_uni)))
    if uni:
        sections.append(("Two-box vs uniform, mean error (agents, same run)", comparison_table(rows, uni)))
    if sens:
        sections.append((f"Sensitivity to the reconstruction: other box sizes ({args.sensitivity_cases} cases per "
                         f"size, closed form, inside {args.inside:g}; 'yes/no' = the paper's statement holds)",
                         report.markdown_table(sens, list(sens[0]))))
    nc = sum(r["not_converged"] for r in rows + uni)
    if nc:
        sections.append(("Runs that did not converge", f"{nc} runs did not converge; they are left out of the means."))
    md_path = report.write_markdown(out / "formation_twobox.md",
                                    "Paper 002 Fig. 9: the two-box distribution", sections)
    written = [csv_path, *extra_csv, md_path]
    if not args.no_png:
        series = [("two-box ", rows, "-o")] + ([("uniform ", uni, ":s")] if uni else [])
        written.append(fc.error_figure(series, out / "formation_twobox.png",
                                       f"Paper 002 Fig. 9 reproduced: two-box distribution, {args.cases} cases per size"))
        written.append(instance_figure(make, out / "formation_twobox_instance.png", max(sizes[-1], 2), args.seed,
                                       args.small_box, args.big_box))
    print("wrote " + ", ".join(map(str, written)))
    return 0 if nc == 0 else 1
