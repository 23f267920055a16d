"""Shared parts of the paper 002 experiments: instance generators, the error sweep, argument lists,
the two-panel error figure and the paper-vs-ours claims table.

Error of a method on one instance = 100 * (its global cost - Hungarian optimum) / optimum, the global
cost being the sum of every robot's cost to its task (paper 002, Section II).
"""
from __future__ import annotations

import math
import os
import statistics
import time
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from runtime.allocation.formation.assignment import hungarian, percent_error, straight_line_costs
from runtime.allocation.formation.deferred_acceptance import bs_outcome, rtma_outcome
from runtime.allocation.formation import simulate
from runtime.allocation.formation.simulate import BusParams, solve
from runtime.errors import InputError
from runtime.log import get_logger
from sitl.experiments import report

log = get_logger("experiments.formation")

METHODS = tuple(m for m in simulate.METHODS if m != "hungarian")      # the registry's formation solvers
# BS and RTMA end in the deferred-acceptance matching whatever the message order
# (runtime.allocation.formation.deferred_acceptance): large samples are solved in closed form
CLOSED_FORM = {"bs": bs_outcome, "rtma": rtma_outcome}
LABELS = {"bs": "BS", "rtma": "RTMA", "auction": "auction", "hungarian": "optimum"}
FIELD_M = 1000.0          # paper 002 Section IV-A: 1000 x 1000 m, no obstacles

Instance = Callable[[np.random.Generator, int], tuple[np.ndarray, np.ndarray]]


# ---------------------------------------------------------------------- instances

def uniform_instance(rng: np.random.Generator, n: int, size: float = FIELD_M) -> tuple[np.ndarray, np.ndarray]:
    """n robots and n tasks uniform in a ``size`` x ``size`` square (Fig. 8 left)."""
    return rng.uniform(0, size, (n, 2)), rng.uniform(0, size, (n, 2))


def box_points(rng: np.random.Generator, n: int, size: float, small: float, big: float,
               inside: float) -> np.ndarray:
    """n points: ``n_in`` uniform in the centred ``small`` box, the rest uniform in the field outside the
    centred ``big`` box (rejection sampling); ``n_in`` from :func:`inside_count` ("most", Fig. 8 right)."""
    n_in = inside_count(n, inside)
    c = size / 2
    pts = [rng.uniform(c - small / 2, c + small / 2, 2) for _ in range(n_in)]
    while len(pts) < n:
        p = rng.uniform(0, size, 2)
        if max(abs(p[0] - c), abs(p[1] - c)) > big / 2:
            pts.append(p)
    return np.array(pts, dtype=float).reshape(n, 2)


def inside_count(n: int, inside: float) -> int:
    """How many of n points go in the small box: round(inside * n), at least a majority, but (for n >= 2
    and inside < 1) at most n - 1, so that some point is outside; n = 2 gives one of each."""
    if n < 1:
        return 0
    n_in = max(int(round(inside * n)), n // 2 + 1)
    if n >= 2 and inside < 1:
        n_in = min(n_in, n - 1)
    return n_in


def twobox_instance(rng: np.random.Generator, n: int, size: float = FIELD_M, small: float = 400.0,
                    big: float = 700.0, inside: float = 0.75) -> tuple[np.ndarray, np.ndarray]:
    """Robots and tasks drawn independently by :func:`box_points` (Fig. 8 right, as reconstructed)."""
    return box_points(rng, n, size, small, big, inside), box_points(rng, n, size, small, big, inside)


# ---------------------------------------------------------------------- solving

def run_methods(costs: np.ndarray, methods: Sequence[str] = METHODS, optimum: float | None = None,
                positions: np.ndarray | None = None, bus: BusParams = BusParams()) -> dict[str, dict]:
    """Each method on one cost matrix: its assignment, global cost, % error vs ``optimum`` (default: the
    Hungarian optimum of ``costs``), messages and whether it converged."""
    c = np.asarray(costs, dtype=float)
    if optimum is None:
        optimum = hungarian(c)[1]
    out = {}
    for m in methods:
        r = solve(m, c, tasks=positions, bus=bus, until=3600)
        # rounded to 1e-9 %: an optimal assignment summed in another order differs by ~1e-14 %
        out[m] = {"assignment": r.assignment, "cost": r.cost, "error": round(percent_error(r.cost, optimum), 9) + 0.0,
                  "messages": r.messages, "rounds": r.rounds, "converged": r.converged}
    return out


def error_sweep(instance: Instance, sizes: Sequence[int], cases: int, seed: int,
                methods: Sequence[str] = METHODS, label: str = "") -> list[dict]:
    """``cases`` instances per size (straight-line costs); one row per (size, method) with the mean,
    max and min % error vs the Hungarian optimum, mean messages and rounds, and non-converged runs.
    Instances of size n come from ``np.random.default_rng(seed * 1000 + n)``."""
    rows = []
    for n in sizes:
        rng = np.random.default_rng(seed * 1000 + n)
        acc: dict[str, dict[str, list]] = {m: {"error": [], "messages": [], "rounds": []} for m in methods}
        failed = dict.fromkeys(methods, 0)
        agree = dict.fromkeys(methods, 0)
        cpu = dict.fromkeys(methods, 0.0)
        for _ in range(cases):
            robots, tasks = instance(rng, n)
            costs = straight_line_costs(robots, tasks)
            optimum = hungarian(costs)[1]
            for m in methods:
                t0 = time.process_time()
                res = run_methods(costs, (m,), optimum, tasks)[m]
                cpu[m] += time.process_time() - t0
                if not res["converged"]:
                    failed[m] += 1
                    continue
                if m in CLOSED_FORM:
                    agree[m] += res["assignment"] == CLOSED_FORM[m](costs)
                for k in acc[m]:
                    acc[m][k].append(res[k])
        for m in methods:
            e = acc[m]["error"]
            rows.append({"distribution": label, "robots": n, "method": m, "cases": cases,
                         "mean_error_pct": statistics.fmean(e) if e else math.nan,
                         "max_error_pct": max(e) if e else math.nan,
                         "min_error_pct": min(e) if e else math.nan,
                         "optimal_cases": sum(abs(x) < 1e-9 for x in e),
                         "mean_messages": statistics.fmean(acc[m]["messages"]) if e else math.nan,
                         "mean_rounds": statistics.fmean(acc[m]["rounds"]) if e else math.nan,
                         "not_converged": failed[m], "cpu_s": cpu[m],
                         "same_as_closed_form": agree[m] if m in CLOSED_FORM else ""})
        log.info("%s n=%d: %s", label, n, ", ".join(
            f"{m} {r['mean_error_pct']:.2f}/{r['max_error_pct']:.2f}" for m, r in
            ((r["method"], r) for r in rows[-len(methods):])))
    return rows


def closed_form_errors(instance: Instance, n: int, cases: int, repeats: int, seed: int,
                       methods: Sequence[str]) -> dict[str, np.ndarray]:
    """% error of each closed-form method on ``repeats`` samples of ``cases`` instances of size n, as a
    (repeats, cases) array per method.  The instances are drawn from the same stream as
    :func:`error_sweep`'s, so sample 0 holds the very instances the agents ran."""
    rng = np.random.default_rng(seed * 1000 + n)
    out = {m: np.empty((repeats, cases)) for m in methods if m in CLOSED_FORM}
    rows = np.arange(n)
    for r in range(repeats):
        for k in range(cases):
            robots, tasks = instance(rng, n)
            costs = straight_line_costs(robots, tasks)
            optimum = hungarian(costs)[1]
            for m, errors in out.items():
                errors[r, k] = percent_error(float(costs[rows, CLOSED_FORM[m](costs)].sum()), optimum)
    return out


def closed_form_sweep(instance: Instance, sizes: Sequence[int], cases: int, repeats: int, seed: int,
                      methods: Sequence[str], label: str = "", workers: int | None = None,
                      cluster: str | None = None) -> dict[int, dict[str, np.ndarray]]:
    """:func:`closed_form_errors` for every size, the sizes spread over ``workers`` processes (default: one per
    CPU) or ``cluster`` (the sweep executor); ``instance`` must be picklable (a module-level function or a
    functools.partial)."""
    from sitl.experiments import executor

    methods = [m for m in methods if m in CLOSED_FORM]
    if not methods:
        return {}
    workers = workers or os.cpu_count() or 1
    out: dict[int, dict[str, np.ndarray]] = {}
    order = sorted(sizes, reverse=True)          # largest sizes first: they take longest
    tasks = [(instance, n, cases, repeats, seed, methods) for n in order]
    for k, errors in executor.run_each(closed_form_errors, tasks, workers, cluster):
        out[order[k]] = errors
        log.info("%s closed form n=%d: %d samples of %d cases (%d/%d sizes)", label, order[k], repeats, cases,
                 len(out), len(sizes))
    return {n: out[n] for n in sorted(out)}


def sample_statistics(errors: dict[int, dict[str, np.ndarray]]) -> list[dict]:
    """Rows (size, method) over all samples: mean error with its 95 % confidence half-width (normal
    approximation over every instance), and the max error one sample of ``cases`` instances gives
    (the paper's Fig. 7 statistic): its mean over the samples, standard deviation, 5th and 95th percentiles."""
    rows = []
    for n in sorted(errors):
        for m, e in errors[n].items():
            flat = e.ravel()
            sample_max = e.max(axis=1)
            half = 1.96 * float(flat.std(ddof=1)) / math.sqrt(flat.size) if flat.size > 1 else math.nan
            rows.append({"robots": n, "method": m, "samples": e.shape[0], "cases_per_sample": e.shape[1],
                         "mean_error_pct": float(flat.mean()), "mean_ci95_pct": half,
                         "sample_mean_p5_pct": float(np.percentile(e.mean(axis=1), 5)),
                         "sample_mean_p95_pct": float(np.percentile(e.mean(axis=1), 95)),
                         "expected_max_pct": float(sample_max.mean()),
                         "max_sd_pct": float(sample_max.std(ddof=1)) if e.shape[0] > 1 else math.nan,
                         "max_p5_pct": float(np.percentile(sample_max, 5)),
                         "max_p95_pct": float(np.percentile(sample_max, 95))})
    return rows


def mean_of_max_per_sample(errors: dict[int, dict[str, np.ndarray]], method: str) -> np.ndarray:
    """Per sample: the mean over sizes of that sample's max error (the paper's summary of Fig. 7)."""
    return np.mean([errors[n][method].max(axis=1) for n in sorted(errors)], axis=0)


def percentile_of(value: float, samples: np.ndarray) -> float:
    """Share of ``samples`` at or below ``value``, in %."""
    return 100.0 * float(np.mean(np.asarray(samples) <= value))


def by_method(rows: Sequence[dict], method: str, key: str) -> list[float]:
    """``key`` of ``method``'s rows in size order."""
    return [r[key] for r in sorted((r for r in rows if r["method"] == method), key=lambda r: r["robots"])]


def mean_of_max(rows: Sequence[dict], method: str) -> float:
    """Mean over sizes of the max error (the paper's summary of Fig. 7)."""
    v = [x for x in by_method(rows, method, "max_error_pct") if not math.isnan(x)]
    return statistics.fmean(v) if v else math.nan


# ---------------------------------------------------------------------- arguments

def parse_ints(text: str, what: str, lo: int = 1, hi: int | None = None) -> tuple[int, ...]:
    """Comma-separated integers in [lo, hi], e.g. ``"4,6,8"``; InputError naming ``what`` otherwise."""
    try:
        out = tuple(int(x) for x in str(text).split(","))
    except ValueError:
        raise InputError(f"{what} {text!r}: expected comma-separated integers") from None
    bound = f"{lo}..{hi}" if hi is not None else f">= {lo}"
    if not out or any(v < lo or (hi is not None and v > hi) for v in out):
        raise InputError(f"{what} {text!r}: expected integers {bound}")
    return out


def parse_names(text: str, what: str, allowed: Sequence[str]) -> tuple[str, ...]:
    """Comma-separated names from ``allowed`` (order kept, duplicates dropped)."""
    out: list[str] = []
    for name in str(text).split(","):
        name = name.strip()
        if name not in allowed:
            raise InputError(f"{what} {text!r}: expected a comma-separated subset of {','.join(allowed)}")
        if name not in out:
            out.append(name)
    return tuple(out)


def positive(value: float, what: str, upper: float | None = None) -> float:
    """``value`` if finite and > 0 (and <= ``upper``), else InputError."""
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0
            and (upper is None or value <= upper)):
        bound = f"in (0, {upper}]" if upper is not None else "> 0"
        raise InputError(f"{what} {value!r}: expected a finite number {bound}")
    return float(value)


def add_sweep_arguments(parser, cases: int = 100, max_robots: int = 20, repeats: int = 1000) -> None:
    parser.add_argument("--cases", type=int, default=cases, help=f"random instances per size (paper: {cases})")
    parser.add_argument("--min-robots", type=int, default=2)
    parser.add_argument("--max-robots", type=int, default=max_robots, help="largest n (robots = tasks)")
    parser.add_argument("--methods", default=",".join(METHODS), help="comma-separated subset of bs,rtma,auction")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=repeats,
                        help="samples of --cases instances solved in closed form for BS and RTMA (the first "
                             "sample is also run as agents): expected values and spreads (default %(default)s)")
    parser.add_argument("--no-png", action="store_true", help="skip the figure")


def sweep_sizes(args) -> range:
    if args.cases < 1:
        raise InputError(f"--cases {args.cases}: expected at least 1")
    if getattr(args, "repeats", 1) < 1:
        raise InputError(f"--repeats {args.repeats}: expected at least 1")
    if not 2 <= args.min_robots <= args.max_robots <= 250:
        raise InputError(f"--min-robots {args.min_robots} --max-robots {args.max_robots}: "
                         "expected 2 <= min <= max <= 250")
    return range(args.min_robots, args.max_robots + 1)


# ---------------------------------------------------------------------- output

def error_table(rows: Sequence[dict], methods: Sequence[str], paper: dict | None = None) -> str:
    """Markdown: one line per size, mean and max error and mean messages per method."""
    table = []
    for n in sorted({r["robots"] for r in rows}):
        line: dict = {"robots": n}
        for m in methods:
            r = next((x for x in rows if x["robots"] == n and x["method"] == m), None)
            if r is None:
                continue
            line[f"{LABELS[m]} mean %"] = r["mean_error_pct"]
            line[f"{LABELS[m]} max %"] = r["max_error_pct"]
            line[f"{LABELS[m]} msgs"] = r["mean_messages"]
            if r["not_converged"]:
                line[f"{LABELS[m]} msgs"] = f"{r['mean_messages']:.4g} ({r['not_converged']} not converged)"
        table.append(line)
    cols = ["robots"] + [f"{LABELS[m]} {k}" for m in methods for k in ("mean %", "max %", "msgs")]
    return report.markdown_table(table, cols)


def claims_table(claims: Sequence[tuple[str, str, str, bool | None]]) -> str:
    """Markdown for (what the paper says, paper value, ours, holds?) lines."""
    rows = [{"paper says": c, "paper": p, "ours": o, "holds": "-" if ok is None else ("yes" if ok else "no")}
            for c, p, o, ok in claims]
    return report.markdown_table(rows, ["paper says", "paper", "ours", "holds"])


def error_figure(series: Sequence[tuple[str, Sequence[dict], str]], path: Path, title: str,
                 paper_points: Sequence[tuple[str, str, float | None, float]] = (),
                 expected: Sequence[dict] = ()) -> Path:
    """Two panels, mean and max % error vs robots.  ``series``: (label prefix, rows, line style);
    ``paper_points``: (panel "mean"|"max", label, robots, value) drawn as stars; robots None draws a
    dashed line (a value over all sizes); ``expected``: :func:`sample_statistics` rows, drawn as a line
    with a band (mean: 95 % CI; max: 5th..95th percentile of one sample's max)."""
    fig, _ = report.figure()
    fig.clf()
    axes = fig.subplots(1, 2, sharex=True)
    color = {"bs": "C0", "rtma": "C1", "auction": "C2"}
    for prefix, rows, style in series:
        for m in [m for m in METHODS if any(r["method"] == m for r in rows)]:
            n = by_method(rows, m, "robots")
            for ax, key in zip(axes, ("mean_error_pct", "max_error_pct")):
                ax.plot(n, by_method(rows, m, key), style, color=color[m], ms=3,
                        label=f"{prefix}{LABELS[m]}".strip())
    for m in [m for m in METHODS if any(r["method"] == m for r in expected)]:
        rows = sorted((r for r in expected if r["method"] == m), key=lambda r: r["robots"])
        n = [r["robots"] for r in rows]
        mean = np.array([r["mean_error_pct"] for r in rows])
        ci = np.array([r["mean_ci95_pct"] for r in rows])
        axes[0].plot(n, mean, "-", color=color[m], lw=2, alpha=0.5, label=f"expected {LABELS[m]}")
        axes[0].fill_between(n, mean - ci, mean + ci, color=color[m], alpha=0.2)
        axes[1].plot(n, [r["expected_max_pct"] for r in rows], "-", color=color[m], lw=2, alpha=0.5,
                     label=f"expected {LABELS[m]}")
        axes[1].fill_between(n, [r["max_p5_pct"] for r in rows], [r["max_p95_pct"] for r in rows],
                             color=color[m], alpha=0.15)
    for panel, label, n, v in paper_points:
        ax = axes[0 if panel == "mean" else 1]
        if n is None:                   # a value over all sizes: a dashed line
            ax.axhline(v, ls="--", color="k", lw=0.7)
            ax.annotate(label, (0.02, v), xycoords=("axes fraction", "data"), fontsize=6,
                        xytext=(0, 2), textcoords="offset points")
        else:
            ax.plot([n], [v], "*", color="k", ms=8)
            ax.annotate(label, (n, v), fontsize=6, xytext=(-60, 6), textcoords="offset points")
    for ax, what in zip(axes, ("mean", "max")):
        ax.set_xlabel("robots = tasks")
        ax.set_ylabel(f"{what} error vs Hungarian (%)")
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=6)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    import matplotlib.pyplot as plt
    plt.close(fig)
    return path
