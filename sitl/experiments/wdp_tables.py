"""Paper 001 Tables 3-6: bid-tree nodes and seconds of IDA* and BFS, beside the paper's numbers.

10 robots; 10, 15, 20 tasks; ``random`` bids (10-50 bids, coalition size drawn from 1..10) and
``uniform`` bids (40-160 bids, coalition size 3); each bid names a random task and a random value.
Each cell averages ``--runs`` instances.  BFS (and IDA*) stop at a node cap; a cell where any run
hit it is reported as capped with the cap, not as a number.  Every uncapped run checks that IDA*,
BFS and the DP agree on the optimal value.
"""
from __future__ import annotations

import argparse
import math
import random
import statistics
import time
from pathlib import Path

from runtime.allocation.coalition import winner_determination as wd
from runtime.allocation.coalition.wdp_model import Problem, TaskBid
from runtime.errors import InputError
from runtime.log import get_logger
from sitl.experiments import executor, report

log = get_logger("experiments.wdp_tables")

RANDOM_BIDS = (10, 20, 30, 40, 50)
UNIFORM_BIDS = (40, 70, 100, 130, 160)
TASKS = (10, 15, 20)

# paper 001, Tables 3-6: {(distribution, tasks): {method: [value per bid count]}}
PAPER_NODES = {
    ("random", 10): {"idastar": [24, 75, 105, 136, 345], "bfs": [106, 979, 4681, 9205, 29945]},
    ("random", 15): {"idastar": [26, 93, 146, 189, 420], "bfs": [119, 1154, 6136, 24402, 57530]},
    ("random", 20): {"idastar": [25, 78, 198, 254, 484], "bfs": [163, 2042, 9788, 36604, 130201]},
    ("uniform", 10): {"idastar": [61, 114, 171, 228, 271], "bfs": [2364, 2364, 5240, 9643, 17089]},
    ("uniform", 15): {"idastar": [95, 159, 258, 317, 443], "bfs": [974, 3419, 8051, 15113, 20586]},
    ("uniform", 20): {"idastar": [110, 227, 348, 455, 585], "bfs": [1284, 4531, 10365, 20586, 34796]},
}
PAPER_SECONDS = {
    ("random", 10): {"idastar": [0.02, 0.12, 0.31, 0.43, 1.53], "bfs": [0.01, 0.11, 0.59, 1.32, 4.60]},
    ("random", 15): {"idastar": [0.02, 0.14, 0.33, 0.56, 1.69], "bfs": [0.01, 0.13, 0.70, 3.42, 10.17]},
    ("random", 20): {"idastar": [0.03, 0.15, 0.44, 0.73, 1.72], "bfs": [0.02, 0.23, 0.96, 4.91, 21.70]},
    ("uniform", 10): {"idastar": [0.09, 0.34, 0.78, 1.47, 2.40], "bfs": [0.05, 0.25, 0.75, 1.74, 3.54]},
    ("uniform", 15): {"idastar": [0.13, 0.54, 1.02, 1.78, 3.13], "bfs": [0.07, 0.41, 0.96, 2.24, 4.35]},
    ("uniform", 20): {"idastar": [0.14, 0.55, 1.22, 2.27, 3.71], "bfs": [0.08, 0.38, 1.10, 2.58, 5.13]},
}
PAPER_BIDS = {"random": RANDOM_BIDS, "uniform": UNIFORM_BIDS}


def make_problem(rng: random.Random, n_robots: int, n_tasks: int, n_bids: int, dist: str,
                 sizes: tuple[int, int] = (1, 10), values: tuple[int, int] = (1, 100)) -> Problem:
    """One instance: each bid draws a task, a coalition (``random``: size uniform in ``sizes``,
    capped at the team; ``uniform``: size 3) and an integer value uniform in ``values``."""
    robots = tuple(range(1, n_robots + 1))
    tasks = tuple(range(1, n_tasks + 1))
    bids = []
    for _ in range(n_bids):
        if dist == "random":
            size = rng.randint(sizes[0], min(sizes[1], n_robots))
        elif dist == "uniform":
            size = min(3, n_robots)
        else:
            raise ValueError(f"distribution {dist!r}: expected random or uniform")
        bids.append(TaskBid(rng.choice(tasks), tuple(sorted(rng.sample(robots, size))),
                            float(rng.randint(values[0], values[1]))))
    return Problem(robots, tasks, tuple(bids))


def _range(text: str, what: str) -> tuple[int, int]:
    try:
        lo, hi = (int(x) for x in text.split(","))
    except ValueError:
        raise InputError(f"{what} {text!r}: expected two integers LO,HI") from None
    if not 0 <= lo <= hi:
        raise InputError(f"{what} {text!r}: expected 0 <= LO <= HI")
    return lo, hi


def _ints(text: str, what: str) -> tuple[int, ...]:
    try:
        out = tuple(int(x) for x in text.split(","))
    except ValueError:
        raise InputError(f"{what} {text!r}: expected comma-separated integers") from None
    if not out or min(out) < 1:
        raise InputError(f"{what} {text!r}: expected positive integers")
    return out


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--runs", type=int, default=10, help="instances per cell (paper: 10)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--robots", type=int, default=10)
    parser.add_argument("--tasks", default=",".join(map(str, TASKS)), help="task counts, comma-separated")
    parser.add_argument("--random-bids", default=",".join(map(str, RANDOM_BIDS)))
    parser.add_argument("--uniform-bids", default=",".join(map(str, UNIFORM_BIDS)))
    parser.add_argument("--random-sizes", default="1,10", help="coalition sizes of random bids LO,HI")
    parser.add_argument("--sensitivity-sizes", default="1,4",
                        help="also run the random cells with these coalition sizes LO,HI ('none' to skip)")
    parser.add_argument("--values", default="1,100", help="integer bid values LO,HI")
    parser.add_argument("--node-cap", type=int, default=1_000_000,
                        help="nodes per instance before BFS or IDA* gives up (cell reported as capped)")
    parser.add_argument("--no-png", action="store_true", help="skip the figure")
    # default 1: the tables report seconds, which cells running side by side on shared cores would inflate
    executor.add_arguments(parser, jobs=1, what="cells")


def run_cell(rng: random.Random, dist: str, n_robots: int, n_tasks: int, n_bids: int, runs: int,
             sizes: tuple[int, int], values: tuple[int, int], cap: int) -> dict:
    """Average nodes and seconds of IDA* and BFS over ``runs`` instances of one table cell."""
    acc: dict[str, list] = {k: [] for k in ("ida_nodes", "ida_last", "ida_exp", "ida_iter", "ida_s", "bfs_nodes", "bfs_s")}
    capped = {"idastar": 0, "bfs": 0}
    for _ in range(runs):
        problem = make_problem(rng, n_robots, n_tasks, n_bids, dist, sizes, values)
        exact = wd.solve(problem, "dp").value
        ida = wd.solve(problem, "idastar", node_limit=cap)
        bfs = wd.solve(problem, "bfs", node_limit=cap)
        for name, res in (("idastar", ida), ("bfs", bfs)):
            if res.capped:
                capped[name] += 1
            elif not math.isclose(res.value, exact, rel_tol=1e-9, abs_tol=1e-9):
                raise AssertionError(f"{name} value {res.value} != optimum {exact} ({dist}, {n_tasks} tasks, {n_bids} bids)")
        acc["ida_nodes"].append(ida.nodes)
        acc["ida_last"].append(ida.last_pass_nodes)
        acc["ida_exp"].append(ida.last_pass_expanded)
        acc["ida_iter"].append(ida.iterations)
        acc["ida_s"].append(ida.seconds)
        acc["bfs_nodes"].append(bfs.nodes)
        acc["bfs_s"].append(bfs.seconds)
    mean = {k: statistics.fmean(v) for k, v in acc.items()}
    return {"capped_idastar": capped["idastar"], "capped_bfs": capped["bfs"], **mean}


def seeded_cell(seed: str, *rest) -> dict:
    """:func:`run_cell` with its own generator seeded by ``seed`` (a task of the sweep executor: every cell alike
    wherever and in whatever order it runs)."""
    return run_cell(random.Random(seed), *rest)


def _paper_index(dist: str, n_bids: int) -> int | None:
    bids = PAPER_BIDS[dist]
    return bids.index(n_bids) if n_bids in bids else None


def _ratio_note(ours: float, paper: float) -> str:
    if not paper or not ours:
        return ""
    r = ours / paper
    return f"{r:.2g}x" + (" (>2x)" if r > 2 or r < 0.5 else "")


def run(args: argparse.Namespace) -> int:
    if args.runs < 1:
        raise InputError(f"--runs {args.runs}: expected at least 1")
    if args.node_cap < 1:
        raise InputError(f"--node-cap {args.node_cap}: expected at least 1")
    if args.robots < 1:
        raise InputError(f"--robots {args.robots}: expected at least 1")
    executor.check_arguments(args)
    tasks = _ints(args.tasks, "--tasks")
    cols = {"random": _ints(args.random_bids, "--random-bids"), "uniform": _ints(args.uniform_bids, "--uniform-bids")}
    sizes = _range(args.random_sizes, "--random-sizes")
    if sizes[0] < 1:
        raise InputError(f"--random-sizes {args.random_sizes!r}: coalitions have at least 1 robot")
    values = _range(args.values, "--values")
    out = Path(args.out)
    sens = None if args.sensitivity_sizes == "none" else _range(args.sensitivity_sizes, "--sensitivity-sizes")
    if sens is not None and sens[0] < 1:
        raise InputError(f"--sensitivity-sizes {args.sensitivity_sizes!r}: coalitions have at least 1 robot")
    rows: list[dict] = []
    sens_rows: list[dict] = []
    t0 = time.perf_counter()
    plan = [("random", sizes, rows), ("uniform", sizes, rows)]
    if sens is not None and sens != sizes:
        plan.append(("random", sens, sens_rows))
    specs = [(dist, dsizes, target, n_tasks, n_bids) for dist, dsizes, target in plan for n_tasks in tasks
             for n_bids in cols[dist]]
    cells: dict[int, dict] = {}
    for i, cell in executor.run_each(seeded_cell, [
            (f"{args.seed}/{dist}/{dsizes}/{n_tasks}/{n_bids}", dist, args.robots, n_tasks, n_bids, args.runs, dsizes,
             values, args.node_cap) for dist, dsizes, _, n_tasks, n_bids in specs], args.jobs, args.cluster):
        cells[i] = cell
        dist, dsizes, _, n_tasks, n_bids = specs[i]
        log.info("%s %s %d tasks %d bids: ida %.0f bfs %.0f (%d/%d cells)", dist, dsizes, n_tasks, n_bids,
                 cell["ida_nodes"], cell["bfs_nodes"], len(cells), len(specs))
    for i, (dist, dsizes, target, n_tasks, n_bids) in enumerate(specs):
        cell = cells[i]
        k = _paper_index(dist, n_bids)
        paper = (dist, n_tasks) in PAPER_NODES and k is not None and args.robots == 10
        row = {"distribution": dist, "random_sizes": f"{dsizes[0]}-{dsizes[1]}" if dist == "random" else "3",
               "tasks": n_tasks, "bids": n_bids, "runs": args.runs,
               "idastar_nodes": cell["ida_nodes"], "idastar_last_pass_nodes": cell["ida_last"],
               "idastar_last_pass_expanded": cell["ida_exp"], "idastar_passes": cell["ida_iter"],
               "paper_idastar_nodes": PAPER_NODES[(dist, n_tasks)]["idastar"][k] if paper else float("nan"),
               "bfs_nodes": cell["bfs_nodes"],
               "paper_bfs_nodes": PAPER_NODES[(dist, n_tasks)]["bfs"][k] if paper else float("nan"),
               "idastar_s": cell["ida_s"],
               "paper_idastar_s": PAPER_SECONDS[(dist, n_tasks)]["idastar"][k] if paper else float("nan"),
               "bfs_s": cell["bfs_s"],
               "paper_bfs_s": PAPER_SECONDS[(dist, n_tasks)]["bfs"][k] if paper else float("nan"),
               "idastar_capped_runs": cell["capped_idastar"], "bfs_capped_runs": cell["capped_bfs"],
               "node_cap": args.node_cap}
        target.append(row)
    elapsed = time.perf_counter() - t0
    report.write_csv(out / "wdp_tables.csv", rows + sens_rows)
    sections = _sections(rows, args, sizes, values, elapsed)
    if sens_rows:
        sections.insert(-1, (f"Sensitivity: random bids with coalition sizes {sens[0]}..{sens[1]} (nodes)",
                             _node_tables(sens_rows)))
    report.write_markdown(out / "wdp_tables.md", "Paper 001 Tables 3-6: winner determination, IDA* vs BFS", sections)
    if not args.no_png:
        _figure(rows, out / "wdp_tables.png")
    print(f"wrote {out / 'wdp_tables.csv'}, {out / 'wdp_tables.md'}" + ("" if args.no_png else f", {out / 'wdp_tables.png'}"))
    return 0


NOTES = {
    "A": ("BFS, random bids: the tree size depends only on which coalitions conflict, not on values. "
          "The paper draws random coalition sizes from 1..10 (mean 5.5 of 10 robots) yet reports random "
          "trees far larger than its size-3 uniform trees; larger coalitions conflict more and give smaller "
          "trees, so its random coalitions must have been smaller than stated. With the stated sizes our "
          "trees are 2-50x smaller; the sensitivity table redraws the random bids with small coalitions "
          "and lands near the paper's counts."),
    "B": ("BFS, uniform bids: same generator as the paper as far as it is stated (size 3, random task, "
          "random robots). The paper lists 2364 nodes for both 40 and 70 bids at 10 tasks while its tree "
          "grows with the bid count in every other row, so its 40-bid entry looks copied from the 70-bid "
          "one; our 70-bid count is within 2x of 2364. Other differences are sampling (10 runs)."),
    "C": ("IDA*: the paper does not say which nodes it counts. Its IDA* spends about 70x more seconds "
          "per counted node than its BFS (uniform, 10 tasks, 40 bids: 61 nodes in 0.09 s against 2364 "
          "nodes in 0.05 s), which only fits if most generated nodes were not counted; of the counts we "
          "measure, the nodes expanded in the final pass track the paper's for uniform bids ({uniform_ida} "
          "cells within 2x in this run), so the paper's numbers sit beside those and the other two counts are listed. For "
          "random bids our final pass stays 2-10x smaller than the paper's, also with small coalitions "
          "(sensitivity table) and with the other value laws we tried at 10 tasks and sizes 1..4 "
          "(integers 1..10, 1..1000, size x 1..100, reals in [0, 1): 50-155 expanded nodes at 50 bids "
          "against 345). The "
          "paper gives no more about its random values, so this part stays open: a generator detail we "
          "could not recover, not a difference in the search."),
}


def _cell(ours: float, capped: int, runs: int, cap: int, paper: float, digits: str = ".0f") -> str:
    if capped:
        return f"capped at {cap} ({capped}/{runs} runs)"
    text = format(ours, digits)
    if paper == paper:                   # not nan
        text += f" ({format(paper, digits if digits != '.0f' else '.0f')})"
    return text


def _sections(rows: list[dict], args, sizes, values, elapsed: float) -> list[tuple[str, str]]:
    secs = []
    secs.append(("Setup", (
        f"{args.robots} robots, {args.runs} runs per cell, seed {args.seed}; random bids: coalition size "
        f"uniform in {sizes[0]}..{sizes[1]}; uniform bids: size 3; task uniform; value integer uniform in "
        f"{values[0]}..{values[1]}. Node cap {args.node_cap} per instance. Nodes are generated nodes, root "
        f"excluded, dummy bids included. Each cell shows ours (paper). IDA* all passes = every node generated "
        f"in every pass; last pass = the final pass only, counting the nodes generated or only those expanded "
        f"(g + h at or above the threshold); the paper's IDA* numbers sit beside the last pass, expanded "
        f"(note C). Every uncapped run was checked against the DP optimum. "
        f"Command: `mrta experiment wdp-tables --runs {args.runs} --node-cap {args.node_cap} --seed {args.seed} "
        f"{executor.command_flags(args)}`. "
        f"Wall time {elapsed:.1f} s.")))
    titles = {("random", "nodes"): "Table 3: nodes, random bids", ("random", "s"): "Table 4: seconds, random bids",
              ("uniform", "nodes"): "Table 5: nodes, uniform bids", ("uniform", "s"): "Table 6: seconds, uniform bids"}
    for dist in ("random", "uniform"):
        drows = [r for r in rows if r["distribution"] == dist]
        if not drows:
            continue
        bids = sorted({r["bids"] for r in drows})
        for kind in ("nodes", "s"):
            table = []
            for n_tasks in sorted({r["tasks"] for r in drows}):
                for label, key, paper_key, cap_key in (
                        ("IDA* last pass, expanded", "idastar_last_pass_expanded", "paper_idastar_nodes", "idastar_capped_runs"),
                        ("IDA* last pass, generated", "idastar_last_pass_nodes", None, "idastar_capped_runs"),
                        ("IDA* all passes, generated", "idastar_nodes", None, "idastar_capped_runs"),
                        ("BFS", "bfs_nodes", "paper_bfs_nodes", "bfs_capped_runs")) if kind == "nodes" else (
                        ("IDA*", "idastar_s", "paper_idastar_s", "idastar_capped_runs"),
                        ("BFS", "bfs_s", "paper_bfs_s", "bfs_capped_runs")):
                    line = {"tasks": n_tasks, "method": label}
                    for b in bids:
                        r = next((x for x in drows if x["tasks"] == n_tasks and x["bids"] == b), None)
                        if r is None:
                            continue
                        paper = r[paper_key] if paper_key else float("nan")
                        line[str(b)] = _cell(r[key], r[cap_key], r["runs"], r["node_cap"], paper,
                                             ".0f" if kind == "nodes" else ".3f")
                    table.append(line)
            secs.append((titles[(dist, kind)], report.markdown_table(table, ["tasks", "method"] + [str(b) for b in bids])))
    flagged = []
    for r in rows:
        for label, key, paper_key, cap_key, note in (
                ("IDA* (last pass, expanded)", "idastar_last_pass_expanded", "paper_idastar_nodes", "idastar_capped_runs",
                 "A, C" if r["distribution"] == "random" else "C"),
                ("BFS", "bfs_nodes", "paper_bfs_nodes", "bfs_capped_runs", "A" if r["distribution"] == "random" else "B")):
            paper = r[paper_key]
            if paper != paper or r[cap_key]:
                continue
            ratio = r[key] / paper
            if ratio > 2 or ratio < 0.5:
                flagged.append({"distribution": r["distribution"], "tasks": r["tasks"], "bids": r["bids"],
                                "method": label, "ours": round(r[key]), "paper": paper,
                                "ours/paper": f"{ratio:.2f}", "why": f"note{'s' if ',' in note else ''} {note}"})
    body = (report.markdown_table(flagged, ["distribution", "tasks", "bids", "method", "ours", "paper", "ours/paper", "why"])
            if flagged else "No uncapped cell differs from the paper by more than 2x.")
    capped = [r for r in rows if r["idastar_capped_runs"] or r["bfs_capped_runs"]]
    if capped:
        body += "\n\nCapped cells (not compared): " + ", ".join(
            f"{r['distribution']} {r['tasks']} tasks {r['bids']} bids" for r in capped) + "."
    secs.append(("Cells more than 2x from the paper, and why", body))
    uni = [r for r in rows if r["distribution"] == "uniform" and r["paper_idastar_nodes"] == r["paper_idastar_nodes"]
           and not r["idastar_capped_runs"]]
    close = sum(0.5 <= r["idastar_last_pass_expanded"] / r["paper_idastar_nodes"] <= 2 for r in uni)
    notes = {k: v.format(uniform_ida=f"{close} of {len(uni)}") for k, v in NOTES.items()}
    secs.append(("Notes", "\n\n".join(f"**{k}.** {v}" for k, v in notes.items())))
    return secs


def _node_tables(rows: list[dict]) -> str:
    bids = sorted({r["bids"] for r in rows})
    table = []
    for n_tasks in sorted({r["tasks"] for r in rows}):
        for label, key, paper_key, cap_key in (
                ("IDA* last pass, expanded", "idastar_last_pass_expanded", "paper_idastar_nodes", "idastar_capped_runs"),
                ("BFS", "bfs_nodes", "paper_bfs_nodes", "bfs_capped_runs")):
            line = {"tasks": n_tasks, "method": label}
            for r in rows:
                if r["tasks"] == n_tasks:
                    line[str(r["bids"])] = _cell(r[key], r[cap_key], r["runs"], r["node_cap"], r[paper_key])
            table.append(line)
    return report.markdown_table(table, ["tasks", "method"] + [str(b) for b in bids])


def _figure(rows: list[dict], path: Path) -> Path:
    fig, _ = report.figure()
    fig.clf()
    axes = fig.subplots(1, 2, sharey=True)
    colors = {}
    for ax, dist in zip(axes, ("random", "uniform")):
        drows = [r for r in rows if r["distribution"] == dist]
        for n_tasks in sorted({r["tasks"] for r in drows}):
            rs = sorted((r for r in drows if r["tasks"] == n_tasks), key=lambda r: r["bids"])
            c = colors.setdefault(n_tasks, f"C{len(colors)}")
            x = [r["bids"] for r in rs]
            nan = float("nan")                      # capped cells are not numbers: left out
            ax.plot(x, [nan if r["bfs_capped_runs"] else r["bfs_nodes"] for r in rs], "-o", color=c, ms=3,
                    label=f"BFS {n_tasks} tasks")
            ax.plot(x, [nan if r["idastar_capped_runs"] else r["idastar_last_pass_expanded"] for r in rs], "-s",
                    color=c, ms=3, alpha=0.6, label=f"IDA* last pass, expanded, {n_tasks} tasks")
            ax.plot(x, [r["paper_bfs_nodes"] for r in rs], "--o", color=c, ms=3, mfc="none", label=f"paper BFS {n_tasks}")
            ax.plot(x, [r["paper_idastar_nodes"] for r in rs], ":s", color=c, ms=3, mfc="none", label=f"paper IDA* {n_tasks}")
        ax.set_yscale("log")
        ax.set_title(f"{dist} bids")
        ax.set_xlabel("bids")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("nodes in the bid tree")
    axes[1].legend(fontsize=5, ncol=2, loc="lower right")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    import matplotlib.pyplot as plt
    plt.close(fig)
    return path
