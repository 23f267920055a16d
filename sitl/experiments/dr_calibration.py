"""Paper 000 section 4.2.1 and Fig. 2: the off-line interference calibration, in the pybullet foraging world.

One object of unlimited weight at distance d from the delivery point D, 1..8 robots all committed to it from the
start (fixed commitments, no agent), load 2 wu per trip, 0.25 m/s (3 du/tu), loading and unloading 0.12 s per wu,
for 4800 s (40,000 tu).  Ten distances: the paper's seven (140 ... 400 du = 1.40 ... 4.00 m) and three that
cover the rest of the 10 x 10 m arena (100, 450 and 525 du).  Robots load within 0.3 m of the object and unload
within 1 m of D's centre (the delivery area), as in the foraging runs, and d is the way from the object to that
area's edge (the dr agents measure it so too): objects appear 2 m from D's centre at the least (1 m from the
area) and, 0.5 m inside the walls, 6.36 m at the most (5.36 m from the area).  The object lies on the diagonal from D, so the longest fits.
Each (n, d) gives one sample of the interference model's training set (80 = n_v):

    I = n * workCapacity(d) - weight moved / duration        (wu/s),
    workCapacity(d) = L v / (2 (tau L v + d))                  (eq. 5, tau = 0.12 s/wu)

The samples go to ``--samples`` (default results/dr-calibration/samples.csv; columns n, d_m, I_wu_per_s and
more) for the lead to fit the SVR of runtime/allocation/dr/interference.py; CSV, PNG (Fig. 2: weight moved vs
robots, one line per distance) and markdown (the paper's check beside ours) under ``--out``.
"""
from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from runtime.errors import InputError
from runtime.log import get_logger
from sitl.experiments.progress import Progress
from sitl.experiments import executor, report
from sitl.foraging import scenario

log = get_logger("experiments.dr_calibration")

PAPER_DU = (140, 180, 250, 280, 330, 360, 400)      # Fig. 2's D1..D7
EXTRA_DU = (100, 450, 525)                          # ours: the rest of the arena (objects lie 1-5.4 m from D's area)
DURATION = 40000 * scenario.TU                      # 4800 s
LOAD, SPEED, LOAD_TIME = 2.0, 0.25, scenario.TU     # wu, m/s, s per wu
PAPER_FRACTION_8_AT_140 = 0.413                     # Fig. 2 text: 8 robots at D1 reach 41.3 % of ideal
SHIPPED_MODEL = "runtime/allocation/dr/interference_pioneer3dx.json"   # the model the configs and experiments use
CHECK_CASE = (4, 140)                               # the point measured again at a finer physics step
BACKGROUND_AT = 3.0         # m from D's centre: --background's two objects (about where the tables' objects lie) ...
BACKGROUND_TURN = 120.0     # deg: ... this far either side of the fixed object's bearing
SETTINGS = ("duration_s", "dt_s", "control_s", "seed", "lookahead_m", "max_turn_rate", "reach_m",
            "delivery_reach_m", "sonar", "background")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robots", default="1-8", help="group sizes, a range or a comma list (default 1-8)")
    parser.add_argument("--distances", default=",".join(map(str, sorted(PAPER_DU + EXTRA_DU))),
                        help="object-to-D distances in du (1 du = 1 cm), comma-separated")
    parser.add_argument("--duration", type=float, default=DURATION, help="simulated s per case (40,000 tu = 4800 s)")
    parser.add_argument("--seed", type=int, default=1, help="robot starts (and nothing else: the world is exact)")
    parser.add_argument("--dt", type=float, default=None, help="physics step (s; default: the world's, 0.05)")
    parser.add_argument("--check-dt", type=float, default=0.01,
                        help="finer physics step at which the check point (4 robots, 140 du) is run again (0: skip)")
    executor.add_arguments(parser, what="cases")
    parser.add_argument("--quick", action="store_true",
                        help="a small size for tests: robots 1,2,4 at 140 and 400 du for 300 s, no dt check")
    parser.add_argument("--ship", action="store_true",
                        help=f"also write the fitted model over the shipped one ({SHIPPED_MODEL})")
    parser.add_argument("--samples", default="results/dr-calibration/samples.csv",
                        help="where the model's training samples go (default %(default)s)")
    parser.add_argument("--resume", default=None, metavar="CSV",
                        help="a dr_calibration.csv of an earlier run with the same settings: its cases are kept")
    parser.add_argument("--no-png", action="store_true", help="skip the figure")
    parser.add_argument("--background", type=int, default=0, metavar="N",
                        help="not the paper's: two more objects, %g m from D at +-%g deg from the fixed one, each worked "
                             "by N more robots throughout, so the samples include other groups' traffic at D's area, as "
                             "in the tables' three-object world (default 0: the paper's one object)"
                        % (BACKGROUND_AT, BACKGROUND_TURN))


def _robots(text: str) -> tuple[int, ...]:
    try:
        if "-" in text:
            lo, hi = (int(v) for v in text.split("-"))
            out = tuple(range(lo, hi + 1))
        else:
            out = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"--robots {text!r}: expected a range like 1-8 or a list like 1,2,4") from None
    if not out or min(out) < 1 or max(out) > 20:
        raise InputError(f"--robots {text!r}: expected group sizes between 1 and 20")
    return out


def _distances(text: str) -> tuple[int, ...]:
    try:
        out = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"--distances {text!r}: expected whole du (cm) separated by commas") from None
    reach = ((10.0 / 2 - 0.5) * math.sqrt(2) - 1.0) * 100          # the diagonal less the delivery area
    if not out or min(out) < 50 or max(out) > reach:
        raise InputError(f"--distances {text!r}: expected du between 50 and {reach:.0f} (the arena's half diagonal "
                         f"less the delivery area, 0.5 m inside the walls)")
    return out


def work_capacity(d_m: float) -> float:
    """Eq. 5 for the calibration's robots (wu/s)."""
    return scenario.work_capacity(d_m, LOAD, SPEED, LOAD_TIME)


def background(per_object: int) -> tuple[tuple[float, float, int], ...]:
    """--background's two objects, (x, y, robots) each, about the fixed object's bearing (45 deg, the diagonal)."""
    if per_object <= 0:
        return ()
    at = [math.radians(45.0 + s * BACKGROUND_TURN) for s in (-1, 1)]
    return tuple((BACKGROUND_AT * math.cos(a), BACKGROUND_AT * math.sin(a), per_object) for a in at)


def config(n: int, d_du: int, duration: float, seed: int, dt: float, extra: int = 0) -> "harness.ForagingConfig":
    from sitl.foraging import harness          # pybullet: loaded when a case runs, not when the CLI is built

    c = d_du * scenario.DU + harness.ForagingConfig.delivery_reach     # d is to the delivery area's edge
    bg = background(extra)
    return harness.ForagingConfig(robots=n + sum(g[2] for g in bg), method=None, seed=seed, time_limit=duration,
                                  dt=dt, fixed_object=(c / math.sqrt(2), c / math.sqrt(2)), background=bg, load=LOAD,
                                  load_time=LOAD_TIME, speed=SPEED)


def run_case(n: int, d_du: int, duration: float, seed: int, dt: float, extra: int = 0) -> dict:
    """One calibration case: the row of the CSV.  Only the fixed object's weight counts (the first record)."""
    from sitl.foraging import harness

    cfg = config(n, d_du, duration, seed, dt, extra)
    t0 = time.perf_counter()
    res = harness.run(cfg)
    wall = time.perf_counter() - t0
    d = d_du * scenario.DU
    ideal = n * work_capacity(d)
    mine = res.objects[0]
    robots = [res.robots[r] for r in cfg.ids[:n]]
    rate = mine.delivered / res.end
    return {"n": n, "d_du": d_du, "d_m": d, "I_wu_per_s": ideal - rate, "I_wu_per_tu": (ideal - rate) * scenario.TU,
            "moved_wu": mine.delivered, "ideal_wu_per_s": ideal, "actual_wu_per_s": rate, "fraction_of_ideal": rate / ideal,
            "trips": sum(r.trips for r in robots), "stalled_s_mean": float(np.mean([r.stalled for r in robots])),
            "distance_m_mean": float(np.mean([r.distance for r in robots])), "duration_s": res.end, "dt_s": cfg.dt,
            "control_s": cfg.control_period, "seed": seed, "lookahead_m": cfg.lookahead,
            "max_turn_rate": cfg.max_turn_rate, "reach_m": cfg.reach, "delivery_reach_m": cfg.delivery_reach,
            "sonar": cfg.sonar, "background": extra, "wall_s": wall}


def _key(row: dict) -> tuple:
    return (int(row["n"]), int(row["d_du"]), float(row["dt_s"]))


def load_resume(path: str, want: dict) -> dict[tuple, dict]:
    """Rows of an earlier run whose settings match ``want`` (setting -> value), by (n, d_du, dt)."""
    import csv
    p = Path(path)
    if not p.is_file():
        raise InputError(f"--resume {path}: no such file")
    out = {}
    with p.open() as fh:
        for row in csv.DictReader(fh):
            parsed = {k: _parse(v) for k, v in row.items()}
            parsed.setdefault("background", 0)            # rows written before --background existed
            if all(k in parsed and str(parsed[k]) == str(v) for k, v in want.items() if k != "dt_s"):
                out[_key(parsed)] = parsed
    return out


def _parse(v: str):
    for cast in (int, float):
        try:
            return cast(v)
        except ValueError:
            pass
    return {"True": True, "False": False}.get(v, v)


def run_all(cases: list[tuple], args, done: dict[tuple, dict], out_csv: Path) -> dict[tuple, dict]:
    """Run ``cases`` ((n, d_du, dt) each) not in ``done`` through the sweep executor (``--jobs``, ``--cluster``),
    largest groups first; the CSV is rewritten as each finishes, so an interrupted run can ``--resume``."""
    todo = [c for c in cases if c not in done]
    order = sorted(todo, key=lambda c: (-c[0] * (1 + 4 * (c[2] < args.dt)), c[1]))
    progress = Progress(len(cases), log, done=len(cases) - len(todo))     # resumed runs count as done

    def finished(case, row) -> None:
        done[case] = row
        report.write_csv(out_csv, [done[c] for c in cases if c in done])
        progress.step(f"n={case[0]} d={case[1]} du dt={case[2]:.3f}: {row['moved_wu']:.0f} wu moved, "
                      f"{100 * row['fraction_of_ideal']:.1f} % of ideal, I={row['I_wu_per_s']:.4f} wu/s",
                      wall=row["wall_s"])

    tasks = [(c[0], c[1], args.duration, args.seed, c[2], args.background) for c in order]
    for k, row in executor.run_each(run_case, tasks, args.jobs, args.cluster):
        finished(order[k], row)
    return done


# ---------------------------------------------------------------------- report

def fraction_table(rows: list[dict]) -> str:
    """Fraction of eq. 5's ideal per group size (rows) and distance (columns)."""
    ds = sorted({r["d_du"] for r in rows})
    get = {(r["n"], r["d_du"]): r for r in rows}
    table = []
    for n in sorted({r["n"] for r in rows}):
        line = {"robots": n}
        for d in ds:
            r = get.get((n, d))
            line[f"{d} du"] = "-" if r is None else f"{100 * r['fraction_of_ideal']:.1f} %"
        table.append(line)
    return report.markdown_table(table, ["robots"] + [f"{d} du" for d in ds])


def moved_table(rows: list[dict]) -> str:
    """Weight moved (wu) and I (wu/s) per case."""
    out = [{"robots": r["n"], "d (du)": r["d_du"], "moved (wu)": r["moved_wu"], "ideal (wu/s)": r["ideal_wu_per_s"],
            "actual (wu/s)": r["actual_wu_per_s"], "I (wu/s)": r["I_wu_per_s"], "I (wu/tu)": r["I_wu_per_tu"],
            "stalled (s, mean)": r["stalled_s_mean"]} for r in sorted(rows, key=lambda r: (r["d_du"], r["n"]))]
    return report.markdown_table(out)


def claims(rows: list[dict]) -> list[tuple[str, str, str, bool | None]]:
    get = {(r["n"], r["d_du"]): r for r in rows}
    out = []
    r8 = get.get((8, 140))
    if r8 is not None:
        ok = abs(r8["fraction_of_ideal"] - PAPER_FRACTION_8_AT_140) <= 0.1
        out.append(("8 robots at D1 = 140 du reach this share of the ideal capacity (eq. 4)",
                    f"{100 * PAPER_FRACTION_8_AT_140:.1f} %", f"{100 * r8['fraction_of_ideal']:.1f} %", ok))
    ds = sorted({d for _, d in get})
    ns = sorted({n for n, _ in get})
    if len(ns) > 1:
        grows = [d for d in ds if all((n, d) in get for n in ns)
                 and get[(ns[-1], d)]["I_wu_per_s"] > get[(ns[0], d)]["I_wu_per_s"]]
        out.append(("interference grows with the number of robots", "at every distance",
                    f"I({ns[-1]}) > I({ns[0]}) at {len(grows)} of {len(ds)} distances", len(grows) == len(ds)))
        prop = [d for d in ds if all((n, d) in get for n in (1, ns[-1]))
                and get[(ns[-1], d)]["moved_wu"] < ns[-1] * get[(1, d)]["moved_wu"] * 0.95]
        if 1 in ns:
            out.append(("the weight moved is not proportional to the number of robots", "less than proportional",
                        f"{ns[-1]} robots move < 95 % of {ns[-1]} x one robot at {len(prop)} of {len(ds)} distances",
                        len(prop) == len(ds)))
    if len(ds) > 1 and ns:
        n = ns[-1]
        fr = [get[(n, d)]["fraction_of_ideal"] for d in ds if (n, d) in get]
        rising = bool(np.corrcoef(ds[:len(fr)], fr)[0, 1] > 0) if len(fr) > 2 else None
        out.append((f"interference stronger at shorter distances ({n} robots)", "fraction of ideal rises with d",
                    " / ".join(f"{d}: {100 * f:.0f} %" for d, f in zip(ds, fr)), rising))
    return out


def dt_check(rows: list[dict], coarse: float, fine: float) -> str:
    get = {(r["n"], r["d_du"], r["dt_s"]): r for r in rows}
    n, d = CHECK_CASE
    a, b = get.get((n, d, coarse)), get.get((n, d, fine))
    if a is None or b is None:
        return "Not run (`--check-dt 0`, or the check case is not among the cases)."
    rel = (a["I_wu_per_s"] - b["I_wu_per_s"]) / b["I_wu_per_s"] if b["I_wu_per_s"] else math.nan
    return (f"{n} robots at {d} du, physics step {coarse * 1000:g} ms against {fine * 1000:g} ms (control period "
            f"{a['control_s']:g} s in both): moved {a['moved_wu']:.0f} against {b['moved_wu']:.0f} wu, I = "
            f"{a['I_wu_per_s']:.4f} against {b['I_wu_per_s']:.4f} wu/s ({100 * rel:+.1f} %), fraction of ideal "
            f"{100 * a['fraction_of_ideal']:.1f} % against {100 * b['fraction_of_ideal']:.1f} %.")


def figure(rows: list[dict], path: Path) -> Path:
    fig, ax = report.figure()
    for k, d in enumerate(sorted({r["d_du"] for r in rows})):
        pts = sorted((r["n"], r["moved_wu"]) for r in rows if r["d_du"] == d)
        ax.plot([p[0] for p in pts], [p[1] for p in pts], "-o", ms=3, color=f"C{k % 10}",
                label=f"{d} du" + (f" (D{PAPER_DU.index(d) + 1})" if d in PAPER_DU else ""))
        one = next((r for r in rows if r["d_du"] == d), None)
        if one is not None:
            ns = [p[0] for p in pts]
            ax.plot(ns, [n * work_capacity(d * scenario.DU) * one["duration_s"] for n in ns], ":", color=f"C{k % 10}",
                    lw=0.8)
    ax.set_xlabel("robots")
    ax.set_ylabel("weight moved (wu)")
    ax.set_title("Paper 000 Fig. 2 in the pybullet world: weight moved in 40,000 tu (dotted: eq. 4 ideal)", fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    import matplotlib.pyplot as plt
    plt.close(fig)
    return path


def run(args: argparse.Namespace) -> int:
    robots, distances = _robots(args.robots), _distances(args.distances)
    if args.quick:
        robots, distances, args.duration, args.check_dt = (1, 2, 4), (140, 400), 300.0, 0.0
    if not (math.isfinite(args.duration) and args.duration > 0):
        raise InputError(f"--duration {args.duration!r}: expected seconds > 0")
    executor.check_arguments(args)
    if not 0 <= args.background <= 6:
        raise InputError(f"--background {args.background}: expected 0 to 6 robots per background object")
    if args.dt is None:
        from sitl.foraging.world import DT
        args.dt = DT
    out = Path(args.out)
    cases = [(n, d, args.dt) for d in distances for n in robots]
    if args.check_dt and CHECK_CASE[0] in robots and CHECK_CASE[1] in distances:
        cases.append((*CHECK_CASE, args.check_dt))
    sample = config(1, distances[0], args.duration, args.seed, args.dt)
    want = {"duration_s": args.duration, "control_s": sample.control_period, "seed": args.seed,
            "lookahead_m": sample.lookahead, "max_turn_rate": sample.max_turn_rate, "reach_m": sample.reach,
            "delivery_reach_m": sample.delivery_reach, "sonar": sample.sonar, "background": args.background}
    done = load_resume(args.resume, want) if args.resume else {}
    t0 = time.perf_counter()
    done = run_all(cases, args, done, out / "dr_calibration.csv")
    wall = time.perf_counter() - t0
    rows = [done[c] for c in cases]
    main = [r for r in rows if r["dt_s"] == args.dt]
    written = [out / "dr_calibration.csv"]
    samples = [{"n": r["n"], "d_m": r["d_m"], "I_wu_per_s": r["I_wu_per_s"], "I_wu_per_tu": r["I_wu_per_tu"],
                "d_du": r["d_du"], "fraction_of_ideal": r["fraction_of_ideal"], "moved_wu": r["moved_wu"],
                "duration_s": r["duration_s"]} for r in main]
    written.append(report.write_csv(args.samples, samples))
    model, model_text = fit_model(samples, out, args)
    written += model
    from sitl.experiments.dr_common import commit     # scikit-learn: loaded when the command runs
    cmd = (f"mrta experiment dr-calibration --robots {','.join(map(str, robots))} --distances {','.join(map(str, distances))} "
           f"--duration {args.duration:g} --seed {args.seed} --dt {args.dt:g} --check-dt {args.check_dt:g} "
           f"{executor.command_flags(args)}" + (f" --background {args.background}" if args.background else ""))
    setup = (f"One object of unlimited weight on the diagonal from D at distance d, {robots[0]}..{robots[-1]} "
             f"Pioneer-sized robots committed to it from the start (fixed commitments: the real transport executor in "
             f"the real executive, no agent), load {LOAD:g} wu, {SPEED:g} m/s, {LOAD_TIME:g} s per wu to load and to "
             f"unload, reach {sample.reach:g} m at the object and {sample.delivery_reach:g} m at D (the delivery area's "
             f"radius), for {args.duration:g} s; physics step {args.dt * 1000:g} ms, control "
             f"period {sample.control_period:g} s; robots start at seeded random places (seed {args.seed}). "
             f"I = n workCapacity(d) - moved / duration (wu/s; x 0.12 for wu/tu). " + _background_text(args.background)
             + f"Command: `{cmd}` on commit {commit()}: wall time {wall:.0f} s for the cases run now.")
    sections = [("Setup", setup),
                ("Paper's statements (section 4.2.1, Fig. 2) beside ours", _claims_table(claims(main))),
                ("Fraction of the ideal capacity (eq. 4) reached", fraction_table(main)),
                ("Physics step check", dt_check(rows, args.dt, args.check_dt)),
                ("The interference model fitted on these samples", model_text),
                ("Every case", moved_table(main))]
    written.append(report.write_markdown(out / "dr_calibration.md", "Paper 000 section 4.2.1: interference calibration",
                                         sections))
    if not args.no_png:
        written.append(figure(main, out / "dr_calibration.png"))
    print("wrote " + ", ".join(map(str, written)))
    return 0


def _background_text(per_object: int) -> str:
    if not per_object:
        return ""
    return (f"Not the paper's calibration: two more objects of unlimited weight, {BACKGROUND_AT:g} m from D's centre at "
            f"+-{BACKGROUND_TURN:g} deg from the fixed one, each worked by {per_object} more robots throughout (the "
            f"tables' three objects; their groups met at D's area, which a one-object calibration never shows); only "
            f"the fixed object's weight and group enter the sample. ")


def fit_model(samples: list[dict], out: Path, args) -> tuple[list[Path], str]:
    """The SVR of paper 000 section 4.2 fitted on the samples (C and gamma by cross-validated grid search),
    written to ``out``/model.json and, with ``--ship``, over the shipped model; and a paragraph saying what it
    predicts."""
    from runtime.allocation.dr.interference import InterferenceModel

    triples = [(float(r["n"]), float(r["d_m"]), float(r["I_wu_per_s"])) for r in samples]
    if len(triples) < 2:
        return [], "Too few samples to fit a model."
    model = InterferenceModel.from_samples(
        triples, search=True, source=f"mrta experiment dr-calibration: {len(triples)} samples of "
                                     f"{args.duration:g} s each (seed {args.seed})")
    paths = [out / "model.json"]
    model.save(paths[0])
    if args.ship:
        model.save(Path(SHIPPED_MODEL))
        paths.append(Path(SHIPPED_MODEL))
    ds = sorted({r["d_m"] for r in samples})
    ns = sorted({int(r["n"]) for r in samples})
    head = "| n | " + " | ".join(f"{d:.2f} m" for d in ds) + " |\n|---|" + "---|" * len(ds) + "\n"
    body = "".join(f"| {n} | " + " | ".join(f"{model.predict(n, d):.3f}" for d in ds) + " |\n" for n in ns)
    text = (f"epsilon-SVR, RBF kernel, inputs scaled to [0, 1], target standardised; C {model.C:g}, gamma "
            f"{model.gamma:g} chosen by cross-validation on {len(triples)} samples; written to "
            f"{', '.join(map(str, paths))}. Predicted I (wu/s) per group size and distance:\n\n{head}{body}")
    return paths, text


def _claims_table(rows) -> str:
    from sitl.experiments.formation_common import claims_table
    return claims_table(rows)
