"""Shared parts of paper 000's experiment commands (dr-table3, dr-table4, dr-table5): the real ``dr`` agent in the
pybullet foraging harness (:mod:`sitl.foraging.harness`), one run per (cell, seed).

* A **cell** is one strategy of the paper's tables: the auction (dr | sr | greedy), the strategy (M_I | NM_I |
  M_NI | NM_NI), the utility the leaders bid with (soft eq. 10 | hard), on-line learning and the speed belief
  (eq. 5's v).  A **setup** is the scenario: robots, objects present at once, weight, deadline, U_max, time
  limit, how many objects end the run.
* :func:`run_one` runs one (cell, setup, seed) and returns its per-run row and per-object rows; :func:`run_all`
  runs many through the sweep executor (``--jobs`` local processes or ``--cluster``, :mod:`.executor`) with a
  progress bar on the ``mrta.experiments`` logger, each finished run appended to ``OUT/NAME_done.jsonl`` so that
  ``--resume`` goes on after a stop; the model travels with each run (its bytes), so a worker reads nothing of
  the submitting machine's files.
* :func:`estimate`: ``--estimate`` runs one short calibration run per kind of cell and prints the CPU time the
  command would take, without running it.
* :func:`resolve_model` finds the interference model: ``--model PATH``, else a model file shipped in
  runtime/allocation/dr/, else one fitted from the calibration's samples (results/dr-calibration/samples.csv),
  else a one-line InputError naming what to run.
* Statistics: percentages and utilities per run, then mean +- sd over seeds (:func:`pm`).

Units: m, s, wu; the paper's tu and du convert at 1 tu = 0.12 s, 1 du = 1 cm (:mod:`sitl.foraging.scenario`).
"""
from __future__ import annotations

import argparse
import json
import math
import subprocess
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from runtime.allocation.dr.interference import InterferenceModel
from runtime.allocation.dr.options import DrOptions
from runtime.errors import InputError
from runtime.log import get_logger
from sitl.experiments.progress import Progress
from sitl.experiments import executor, report
from sitl.experiments.executor import Carried
from sitl.foraging import scenario
from sitl.foraging.scenario import Dist

log = get_logger("experiments.dr")

ROOT = Path(__file__).resolve().parents[2]
SHIPPED_MODELS = ROOT / "runtime" / "allocation" / "dr"          # *.json there: the shipped model
CALIBRATION_SAMPLES = Path("results/dr-calibration/samples.csv")   # dr-calibration's output (relative to cwd)
DL = 900 * scenario.TU                                             # 108 s
LATE_CAP = 0.6                                                     # Fig. 3's last bin: >= 60 % late
ERROR_SPEED = 0.8 * scenario.DU / scenario.TU                      # §6.3: 0.8 du/tu = 0.0667 m/s
STRATEGIES = ("NM_NI", "NM_I", "M_NI", "M_I")


@dataclass(frozen=True)
class Cell:
    """One strategy of a table: a label and the dr options that make it."""
    label: str
    auction: str = "dr"
    strategy: str = "NM_I"
    utility: str = "hard"
    online: bool = False
    speed_belief: float | None = None
    late: str = "all"                  # eq. 8 cannot hold: award every bidder (the paper) | "fastest"

    @property
    def uses_model(self) -> bool:
        return self.strategy.endswith("_I")


@dataclass(frozen=True)
class Setup:
    """The scenario of a run (paper §6.2.1 by default: 10 robots, 3 objects of 40 wu, DL 108 s, 3600 s)."""
    robots: int = 10
    objects: int = 3
    weight: float = 40.0
    deadline: float = DL
    u_max: tuple[int, int] = (100, 100)             # integers uniform in [lo, hi]
    time_limit: float = 3600.0
    max_objects: int | None = None                  # the run ends when this many are done (or at time_limit)
    size: float = 10.0
    sonar: bool = True
    paper_deadline: float | None = DL               # s: the paper's deadline for this setting (None: no paper's)
    delivery_area: float = scenario.DELIVERY_AREA   # m: robots unload within this of D (distances are to its edge)
    min_distance: float = scenario.MIN_DISTANCE     # m: objects appear this far from D's centre at the least ...
    min_angle: float = scenario.MIN_ANGLE           # deg: ... and this far apart seen from D

    def describe(self) -> str:
        lo, hi = self.u_max
        u = f"U_max {lo}" if lo == hi else f"U_max integers uniform in [{lo}, {hi}]"
        end = f"{self.time_limit:g} s" + ("" if self.max_objects is None else
                                          f" or {self.max_objects} objects done, whichever comes first")
        scaled = (f", {self.deadline / DL:.2f} x the paper's 900 tu: see docs/dr-experiments.md on the deadline"
                  if self.deadline_scaled else "")
        return (f"{self.robots} robots, {self.objects} objects present at once (each replaced at a random place as "
                f"it is done) of {self.weight:g} wu, deadline {self.deadline:g} s ({self.deadline / scenario.TU:.0f} "
                f"tu{scaled}) after the object appears, {u}; a {self.size:g} x {self.size:g} m arena, delivery area of "
                f"{self.delivery_area:g} m radius at its centre (distances are to its edge), objects at least "
                f"{self.min_distance:g} m from its centre and {self.min_angle:g} deg apart seen from it; each run "
                f"lasts {end}; robots avoid by {'sonar and bumpers' if self.sonar else 'bumpers'}")

    @property
    def deadline_scaled(self) -> bool:
        """Whether the deadline differs from the paper's for this setting (a setting with no paper's: never)."""
        return self.paper_deadline is not None and abs(self.deadline - self.paper_deadline) >= 1e-9


def options(cell: Cell, model: Path | None, setup: Setup) -> DrOptions:
    return DrOptions(auction=cell.auction, strategy=cell.strategy, utility=cell.utility, online=cell.online,
                     speed_belief=cell.speed_belief, delivery=(0.0, 0.0), late=cell.late,
                     delivery_reach=setup.delivery_area,
                     model=str(model) if model is not None and (cell.uses_model or cell.online) else None)


def config(cell: Cell, setup: Setup, seed: int, model: Path | None) -> "harness.ForagingConfig":
    from sitl.foraging import harness          # pybullet: loaded when a run starts, not when the CLI is built

    lo, hi = setup.u_max
    return harness.ForagingConfig(robots=setup.robots, method="dr", options=options(cell, model, setup), seed=seed,
                                  time_limit=setup.time_limit, max_objects=setup.max_objects, objects=setup.objects,
                                  weight=Dist.const(setup.weight), deadline=Dist.const(setup.deadline),
                                  u_max=Dist.integers(lo, hi), size=setup.size, delivery=(0.0, 0.0),
                                  sonar=setup.sonar, delivery_reach=setup.delivery_area,
                                  min_distance=setup.min_distance, min_angle=setup.min_angle)


# ---------------------------------------------------------------------- one run

def run_one(cell: Cell, setup: Setup, seed: int, model: Path | Carried | None) -> dict:
    """One run: ``{"run": row, "objects": [row, ...]}`` (plain values, picklable, CSV-ready); a carried model is
    written where the run is (a worker of a cluster) and read from there."""
    from sitl.foraging import harness

    cfg = config(cell, setup, seed, model.path() if isinstance(model, Carried) else model)
    t0 = time.perf_counter()
    fr = harness.ForagingRun(cfg)
    try:
        res = fr.run()
        books = sum(f.delivered for rb in fr.robots.values() for f in rb.node.agent.finished.values())
    finally:
        fr.close()
    wall = time.perf_counter() - t0
    head = {"cell": cell.label, "auction": cell.auction, "strategy": cell.strategy, "utility": cell.utility,
            "online": cell.online, "speed_belief": "" if cell.speed_belief is None else cell.speed_belief,
            "seed": seed}
    objects = [object_row(head, o, res.end) for o in res.objects]
    done = [o for o in objects if o["done"]]
    x = np.array([o["t_over_dl"] for o in done])
    robots = list(res.robots.values())
    run = {**head, "objects_done": len(done), "objects_appeared": len(objects),
           "within_dl_pct": pct(x <= 1.0), "within_1.1dl_pct": pct(x < 1.1), "late60_pct": pct(x >= 1.0 + LATE_CAP),
           "utility_soft": sum(o["utility_soft"] for o in done), "utility_hard": sum(o["utility_hard"] for o in done),
           "utility_max": sum(o["u_max"] for o in done),
           "mean_group": mean([o["mean_group"] for o in objects]), "max_group": max((o["max_group"] for o in objects), default=0),
           "mean_time_s": mean([o["elapsed_s"] for o in done]),
           "moved_wu": res.moved, "books_wu": books, "sim_s": res.end,
           "stalled_s_mean": mean([r.stalled for r in robots]), "messages": res.messages.sent, "wall_s": wall}
    return {"run": run, "objects": objects}


def object_row(head: dict, o: harness.ObjectRecord, end: float) -> dict:
    done = o.finished is not None
    return {**head, "task": o.task, "x_m": o.x, "y_m": o.y, "d_m": math.hypot(o.x, o.y), "weight_wu": o.weight,
            "deadline_s": o.deadline, "u_max": o.u_max, "appeared_s": o.appeared, "done": done,
            "finished_s": o.finished if done else math.nan, "elapsed_s": o.elapsed if done else math.nan,
            "t_over_dl": o.elapsed / o.deadline if done else math.nan, "delivered_wu": o.delivered,
            "utility_soft": o.utility_soft, "utility_hard": o.utility_hard, "mean_group": o.mean_coalition(end),
            "max_group": max(n for _, n in o.coalition)}


def pct(mask: np.ndarray) -> float:
    return 100.0 * float(np.mean(mask)) if len(mask) else math.nan


def mean(values: Sequence[float]) -> float:
    return float(np.mean(values)) if len(values) else math.nan


# ---------------------------------------------------------------------- many runs

def run_all(jobs: Sequence[tuple[Cell, Setup, int]], model: Path | None, workers: int, cluster: str | None = None,
            checkpoint: Path | None = None, done: dict[str, dict] | None = None) -> list[dict]:
    """Every (cell, setup, seed) run, ``workers`` at a time (or on ``cluster``); results in the order of ``jobs``.
    Runs whose :func:`run_key` is in ``done`` are not run again; each new one is appended to ``checkpoint``."""
    done = done or {}
    keys = [run_key(cell, setup, seed, model) for cell, setup, seed in jobs]
    out: list[dict | None] = [done.get(key) for key in keys]
    todo = [k for k, r in enumerate(out) if r is None]
    progress = Progress(len(jobs), log, done=len(jobs) - len(todo))
    if len(todo) < len(jobs):
        log.info("--resume: %d runs kept from %s, %d to run", len(jobs) - len(todo), checkpoint, len(todo))
    carried = Carried.read(model) if model is not None else None
    for k, res in executor.run_each(run_one, [(*jobs[k], carried) for k in todo], workers, cluster):
        out[todo[k]] = res
        if checkpoint is not None:
            with checkpoint.open("a") as fh:
                fh.write(json.dumps({"key": keys[todo[k]], "result": res}) + "\n")
        r = res["run"]
        progress.step(f"{r['cell']} seed {r['seed']}: {r['objects_done']} objects done, {r['moved_wu']:.0f} wu moved, "
                      f"{r['within_dl_pct']:.0f} % <= DL", wall=r["wall_s"])
    return out


def run_key(cell: Cell, setup: Setup, seed: int, model: Path | None) -> str:
    """What makes a run's result: the cell, the setup, the seed and the model's bytes (``--resume`` keeps a run
    only when all four are the same)."""
    digest = Carried.read(model).digest if model is not None else "none"
    return f"{cell!r} {setup!r} seed={seed} model={digest}"


def load_checkpoint(path: Path) -> dict[str, dict]:
    """The finished runs of ``path`` (one JSON object a line), by key; a line cut short by a stop is dropped, and
    the file rewritten without it (so the next run appended starts on a line of its own)."""
    out: dict[str, dict] = {}
    try:
        lines = path.read_text().splitlines()
    except FileNotFoundError:
        return out
    except OSError as exc:
        raise InputError(f"--resume: {path}: cannot read it ({exc.strerror})") from None
    kept = []
    for line in lines:
        try:
            entry = json.loads(line)
            out[entry["key"]] = entry["result"]
            kept.append(line)
        except (ValueError, KeyError, TypeError):
            log.warning("--resume: %s: dropped a line that is not a finished run", path)
    if len(kept) < len(lines) or (lines and not path.read_text().endswith("\n")):
        tmp = path.with_suffix(".tmp")
        tmp.write_text("".join(line + "\n" for line in kept))
        tmp.replace(path)
    return out


@dataclass
class Execution:
    """What one experiment command ran: every run's result, the model's source, the command line, wall time."""
    results: list[dict]
    source: str
    command: str
    wall: float
    written: list[Path]
    late: str = "all"
    online: bool = False
    kept: int = 0                 # runs taken from the checkpoint of an earlier invocation (--resume)

    @property
    def runs(self) -> list[dict]:
        return [r["run"] for r in self.results]

    @property
    def objects(self) -> list[dict]:
        return [o for r in self.results for o in r["objects"]]

    def describe(self, jobs: int) -> str:
        per_run = mean([r["wall_s"] for r in self.runs])
        rule = ("" if self.late == "all" else
                "Leaders that cannot meet eq. 8 add bidders only while each brings the predicted finish forward "
                "(`late: fastest`, ours), not every bidder (the paper's rule); Greedy still awards every bidder. ")
        if self.online:
            rule += ("Every cell that uses the model learns on-line (section 5.4: each finished task's sample is "
                     "shared and every robot refits on its newest 120), not off-line only as the paper's run. ")
        n = len(self.results)
        wall = (f"wall time {self.wall:.0f} s" if not self.kept else
                f"wall time {self.wall:.0f} s for the {n - self.kept} of {n} runs this invocation ran; {self.kept} "
                f"came from an earlier one's checkpoint (--resume), perhaps on an older commit")
        return (rule + f"Command: `{self.command}` on commit {commit()}: {wall} ({per_run:.0f} s per run, {n} runs, "
                f"{jobs} jobs).")


def execute(args, name: str, cells: Sequence[Cell], setup: Setup, extra: str = "") -> Execution:
    """Resolve the model, run every (cell, seed), write the run and object CSVs under ``--out``."""
    out = Path(args.out)
    model, source = resolve_model(args.model, out)
    online = getattr(args, "online", False)
    cells = [replace(c, late=args.late, online=c.online or (online and c.uses_model)) for c in cells]
    jobs = [(cell, setup, seed) for seed in range(1, args.seeds + 1) for cell in cells]
    checkpoint = out / f"{name}_done.jsonl"
    done = load_checkpoint(checkpoint) if args.resume else {}
    out.mkdir(parents=True, exist_ok=True)
    if not args.resume:
        checkpoint.unlink(missing_ok=True)
    t0 = time.perf_counter()
    results = run_all(jobs, model, args.jobs, args.cluster, checkpoint, done)
    wall = time.perf_counter() - t0
    command = (f"mrta experiment {name.replace('_', '-')} --seeds {args.seeds} {executor.command_flags(args)}{extra}"
               + (" --quick" if args.quick else "") + (f" --time-limit {args.time_limit:g}" if args.time_limit else "")
               + (f" --deadline {args.deadline:g}" if args.deadline else "")
               + (" --no-sonar" if args.no_sonar else "") + (f" --late {args.late}" if args.late != "all" else "")
               + (" --online" if online else ""))
    from_checkpoint = {id(r) for r in done.values()}     # run_all hands those results back as they are
    kept = sum(id(r) in from_checkpoint for r in results)
    return Execution(results, source, command, wall, write_rows(out, name, results), args.late, online, kept)


def kind_of(cell: Cell) -> str:
    """The cells that cost alike per simulated second: the auction, and whether robots learn on-line."""
    return cell.auction + (" on-line" if cell.online else "")


def estimate(args, name: str, cells: Sequence[Cell], setup: Setup) -> int:
    """``--estimate``: one calibration run (seed 1) per kind of cell, cut at ``--estimate-time`` simulated s, gives
    CPU s per simulated s and when objects get done (:func:`run_length`); a run of the command lasts until
    ``max_objects`` are done (or its time limit), and the command is every (cell, seed).  Prints the figures; runs
    nothing else."""
    model, source = resolve_model(args.model, Path(args.out))
    online = getattr(args, "online", False)
    cells = [replace(c, late=args.late, online=c.online or (online and c.uses_model)) for c in cells]
    short = replace(setup, time_limit=min(setup.time_limit, args.estimate_time))
    kinds: dict[str, dict] = {}
    for cell in cells:
        if kind_of(cell) in kinds:
            continue
        cpu0 = time.process_time()
        res = run_one(cell, short, 1, model)
        cpu = time.process_time() - cpu0
        r = res["run"]
        kinds[kind_of(cell)] = {"cell": cell.label, "cpu": cpu, "sim": r["sim_s"],
                                "finished": sorted(o["finished_s"] for o in res["objects"] if o["done"])}
        print(f"calibration: {cell.label} seed 1, {r['sim_s']:.0f} simulated s: {cpu:.1f} CPU s "
              f"({r['sim_s'] / cpu:.1f}x real time per core), {r['objects_done']} objects done")
    # two readings of one short run bracket the rate: the whole run's (its start included: slow) and the steady
    # one (first finish to last: few objects, so it can run fast); the estimate is the range between them
    total, lines = [0.0, 0.0], []
    for kind, k in kinds.items():
        n = sum(1 for c in cells if kind_of(c) == kind) * args.seeds
        want = setup.max_objects
        both = [run_length(k["finished"], k["sim"], want, steady) for steady in (True, False)]
        sims = [min(setup.time_limit, needed) if want else setup.time_limit for _, needed in both]   # else the limit
        cpus = [k["cpu"] / k["sim"] * sim for sim in sims]
        total = [t + n * c for t, c in zip(total, cpus)]
        rate, needed = both[1]
        note = ""
        if want and needed > setup.time_limit:
            need = f"about {needed:.0f}" if math.isfinite(needed) else "more (no object was done in the calibration)"
            note = (f"; at the whole run's rate it ends at --time-limit {setup.time_limit:g} s with about "
                    f"{min(want, rate * setup.time_limit):.0f} of {want} objects done: --time-limit {need} s "
                    f"reaches {want}")
        lines.append(f"  {kind}: {n} runs x {cpus[0]:.0f}-{cpus[1]:.0f} CPU s ({sims[0]:.0f}-{sims[1]:.0f} simulated s "
                     f"each at {both[0][0] * 3600:.1f} steady - {rate * 3600:.1f} whole-run objects done per "
                     f"simulated hour){note}")
    command = (f"mrta experiment {name.replace('_', '-')} --seeds {args.seeds}"
               + (f" --objects {args.objects}" if hasattr(args, "objects") else "")
               + (f" --time-limit {args.time_limit:g}" if args.time_limit else "")
               + (f" --deadline {args.deadline:g}" if args.deadline else "") + (" --quick" if args.quick else ""))
    print(f"estimate for {command} (model: {source}):\n" + "\n".join(lines))
    lo, hi = total
    print(f"total: {lo:.0f}-{hi:.0f} CPU s = {lo / 3600:.1f}-{hi / 3600:.1f} CPU h; wall about "
          f"{lo / args.jobs / 3600:.1f}-{hi / args.jobs / 3600:.1f} h on --jobs {args.jobs}, "
          f"{lo / 3600 / 16:.1f}-{hi / 3600 / 16:.1f} h on 16 cores of a --cluster")
    return 0


def run_length(finished: Sequence[float], sim: float, want: int | None, steady: bool = True) -> tuple[float, float]:
    """(objects done per simulated s, simulated s until ``want`` are done: inf if none was done, ``sim`` with no
    ``want``) from one calibration run of ``sim`` s whose objects finished at ``finished`` s.  ``steady``: the rate
    leaves out the start (robots drive out to the first objects): from the first finish to the last, when two or
    more finished; else (or not ``steady``) what was done over the whole run."""
    done = len(finished)
    if steady and done >= 2 and finished[-1] > finished[0]:
        rate = (done - 1) / (finished[-1] - finished[0])
        return rate, (finished[0] + (want - 1) / rate) if want else sim
    rate = done / sim if sim > 0 else 0.0
    if not want:
        return rate, sim
    return rate, want / rate if rate > 0 else math.inf


def objects_setup(args, full: Setup) -> Setup:
    """``full`` ending after ``--objects`` done (or the quick size with U_max in [50, 150]), then the common
    options."""
    if args.objects < 1:
        raise InputError(f"--objects {args.objects}: expected at least 1")
    setup = replace(QUICK, u_max=full.u_max) if args.quick else replace(full, max_objects=args.objects)
    return apply_arguments(setup, args)


# ---------------------------------------------------------------------- the interference model

def shipped_model() -> Path | None:
    found = sorted(SHIPPED_MODELS.glob("*.json"))
    return found[0] if found else None


def resolve_model(arg: str | None, out: Path) -> tuple[Path, str]:
    """(model file, where it came from): ``--model``, the shipped one, or one fitted (and written to ``out``) from
    the calibration's samples; InputError when there is none."""
    if arg:
        path = Path(arg)
        InterferenceModel.load(path)                       # a bad file: one line naming it and the key
        return path.resolve(), f"--model {arg}"
    shipped = shipped_model()
    if shipped is not None:
        return shipped, f"shipped: {_shown(shipped)}"
    if CALIBRATION_SAMPLES.is_file():
        model = InterferenceModel.from_samples(read_samples(CALIBRATION_SAMPLES), search=True,
                                               source=f"fitted by the dr experiments from {CALIBRATION_SAMPLES}")
        out.mkdir(parents=True, exist_ok=True)
        path = out / "model.json"
        model.save(path)
        return path.resolve(), f"fitted from {CALIBRATION_SAMPLES} ({len(model.samples)} samples; C {model.C:g}, " \
                               f"gamma {model.gamma:g}), written to {path}"
    raise InputError(f"no interference model: expected --model PATH, a model file (*.json) in "
                     f"{_shown(SHIPPED_MODELS)}/ or {CALIBRATION_SAMPLES} (run `mrta experiment "
                     f"dr-calibration` first)")


def _shown(path: Path) -> str:
    """``path`` relative to the repository when it is inside it."""
    try:
        return str(path.relative_to(ROOT))
    except ValueError:
        return str(path)


def read_samples(path: Path) -> list[tuple[float, float, float]]:
    import csv
    try:
        with path.open() as fh:
            rows = list(csv.DictReader(fh))
        return [(float(r["n"]), float(r["d_m"]), float(r["I_wu_per_s"])) for r in rows]
    except (KeyError, ValueError, TypeError) as exc:
        raise InputError(f"{path}: expected columns n, d_m, I_wu_per_s with numbers ({exc})") from None


# ---------------------------------------------------------------------- arguments

def add_arguments(parser: argparse.ArgumentParser, seeds: int = 5, online: bool = True) -> None:
    """The options every dr-* command takes; ``online``: also ``--online`` (not for a table whose cells set it)."""
    parser.add_argument("--seeds", type=int, default=seeds, help="runs per cell, seeds 1..N (default %(default)s)")
    executor.add_arguments(parser)
    parser.add_argument("--resume", action="store_true",
                        help="go on after a stop: keep the runs OUT/NAME_done.jsonl holds for the same cell, setup, "
                             "seed and model, run the rest")
    parser.add_argument("--estimate", action="store_true",
                        help="do not run: print the CPU time the command would take, from one short calibration "
                             "run per kind of cell (auction, on-line or not)")
    parser.add_argument("--estimate-time", type=float, default=600.0, metavar="S",
                        help="simulated s of each --estimate calibration run (default %(default)s)")
    parser.add_argument("--quick", action="store_true", help="a small size for tests (a few seconds)")
    parser.add_argument("--model", default=None, metavar="PATH",
                        help="interference model JSON (default: the shipped one in runtime/allocation/dr/, else "
                             "one fitted from results/dr-calibration/samples.csv)")
    parser.add_argument("--time-limit", type=float, default=None, help="simulated s per run (default: the table's)")
    parser.add_argument("--deadline", type=float, default=None,
                        help="s from an object's appearance to its deadline (default: the table's, the paper's "
                             "900 tu = 108 s); see docs/dr-experiments.md on scaling it to the world")
    parser.add_argument("--no-sonar", action="store_true", help="robots avoid by their bumpers only")
    parser.add_argument("--no-png", action="store_true", help="skip the figures")
    parser.add_argument("--late", choices=("all", "fastest"), default="all",
                        help="what a leader does when eq. 8 cannot hold: all (the paper: award every bidder) or "
                             "fastest (ours: add bidders, best first, only while each brings the predicted finish "
                             "forward); Greedy awards every bidder either way (default %(default)s)")
    if online:
        parser.add_argument("--online", action="store_true",
                            help="cells that use the interference model also learn it on-line (section 5.4), "
                                 "not off-line only as the paper's run")


def check_arguments(args) -> None:
    if args.seeds < 1:
        raise InputError(f"--seeds {args.seeds}: expected at least 1")
    executor.check_arguments(args)
    if args.time_limit is not None and not (math.isfinite(args.time_limit) and args.time_limit > 0):
        raise InputError(f"--time-limit {args.time_limit!r}: expected seconds > 0")
    if args.deadline is not None and not (math.isfinite(args.deadline) and args.deadline > 0):
        raise InputError(f"--deadline {args.deadline!r}: expected seconds > 0")
    if not (math.isfinite(args.estimate_time) and args.estimate_time > 0):
        raise InputError(f"--estimate-time {args.estimate_time!r}: expected seconds > 0")


def apply_arguments(setup: Setup, args) -> Setup:
    if args.time_limit is not None:
        setup = replace(setup, time_limit=float(args.time_limit))
    if args.no_sonar:
        setup = replace(setup, sonar=False)
    if args.deadline is not None:
        setup = replace(setup, deadline=float(args.deadline))
    return setup


def deadline_note(setup: Setup) -> str:
    """A sentence on why a run's deadline is not the paper's ('' when it is)."""
    if not setup.deadline_scaled:
        return ""
    return (f" The deadline is {setup.deadline:g} s, not the paper's {DL:g} s: at {DL:g} s no strategy met a single "
            f"deadline in this world (results/dr-table3-paper-dl), so it is set where Greedy, which ignores deadlines, "
            f"meets as many as in the paper (benchmarks/dr_deadline_scale.py; docs/dr-experiments.md).")


QUICK = Setup(robots=5, objects=1, weight=4.0, deadline=60.0, time_limit=60.0, max_objects=None, size=6.0,
              paper_deadline=None)


# ---------------------------------------------------------------------- statistics and report

def pm(values: Sequence[float], digits: int = 1) -> str:
    """``mean +- sd`` over seeds (NaNs left out); the value alone for one, as one run has no spread; '-' for none."""
    v = [x for x in values if isinstance(x, (int, float)) and not math.isnan(x)]
    if not v:
        return "-"
    if len(v) == 1:
        return f"{v[0]:.{digits}f}"
    return f"{np.mean(v):.{digits}f} ± {float(np.std(v, ddof=1)):.{digits}f}"


def seeds_text(seeds: int, unit: str = "cell") -> str:
    """How many seeds each cell ran, and what that means for the spread."""
    return f"{seeds} seeds per {unit}" if seeds > 1 else f"1 seed per {unit}, so no spread is given"


def objects_text(setup: Setup, paper_objects: int, runs: Sequence[dict], label: str, fewer: str) -> str:
    """'The paper moves N objects per run; we stop at M (LABEL: done per run)', then ``fewer`` when M < N."""
    short = not setup.max_objects or setup.max_objects < paper_objects
    return (f"The paper moves {paper_objects} objects per run; we stop at {setup.max_objects or '-'} ({label}: "
            f"{pm([r['objects_done'] for r in runs])})" + (fewer if short else ". "))


def spread_text(seeds: int) -> str:
    """What the tables' ``mean ± sd`` is over, as :func:`pm` prints it."""
    return f"mean ± sd over {seeds} seeds" if seeds > 1 else "one seed, so no spread"


def by_cell(runs: Sequence[dict], label: str, key: str) -> list[float]:
    return [float(r[key]) for r in runs if r["cell"] == label]


def cell_means(runs: Sequence[dict], label: str, key: str) -> float:
    return mean([x for x in by_cell(runs, label, key) if not math.isnan(x)])


def histogram(x: np.ndarray, lo: float = -1.0, cap: float = LATE_CAP, width: float = 0.1) -> tuple[list[str], np.ndarray]:
    """Fig. 3's bins of t/DL - 1, 0.1 wide, each labelled by its edge nearer the deadline: '-0.2' is (-0.3, -0.2],
    '-0' is (-0.1, 0] (on time), '0' is (0, 0.1), '0.5' is [0.5, 0.6), '>=0.6' everything 60 % late or more;
    shares in % of ``x``."""
    k_lo = int(round(-lo / width))
    k_hi = int(round(cap / width))
    labels = [f"-{k * width:.1f}" if k else "-0" for k in range(k_lo - 1, -1, -1)]
    labels[0] = "<=" + labels[0]
    labels += [f"{k * width:.1f}" if k else "0" for k in range(k_hi)] + [f">={cap:g}"]
    counts = np.zeros(len(labels))
    for v in x:
        if v >= cap:
            k = len(labels) - 1
        elif v <= 0:
            k = k_lo - 1 - min(int(math.floor(-v / width)), k_lo - 1)
        else:
            k = k_lo + int(math.floor(v / width))
        counts[k] += 1
    return labels, 100.0 * counts / max(len(x), 1)


def commit() -> str:
    """The git commit the code ran on (and '+dirty' if the work tree differs), for the reports."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                               capture_output=True, text=True, timeout=10).stdout.strip()
        return (head or "unknown") + ("+dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def write_rows(out: Path, name: str, results: Sequence[dict], objects: bool = True) -> list[Path]:
    written = [report.write_csv(out / f"{name}_runs.csv", [r["run"] for r in results])]
    if objects:
        written.append(report.write_csv(out / f"{name}_objects.csv", [o for r in results for o in r["objects"]]))
    return written


def savefig(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


def hist_figure(series: Sequence[tuple[str, np.ndarray]], path: Path, title: str) -> Path:
    """Grouped bars of :func:`histogram` per series."""
    fig, ax = report.figure()
    width = 0.8 / max(len(series), 1)
    labels: list[str] = []
    for k, (name, x) in enumerate(series):
        labels, share = histogram(x)
        ax.bar(np.arange(len(labels)) + (k - (len(series) - 1) / 2) * width, share, width, label=f"{name} ({len(x)})")
    ax.set_xticks(range(len(labels)), labels, fontsize=7)
    ax.set_xlabel("t/DL - 1 (bins 0.1 wide, labelled by the edge nearer DL)")
    ax.set_ylabel("% of tasks done")
    ax.set_title(title, fontsize=9)
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=7)
    return savefig(fig, path)


def bar_figure(groups: Sequence[tuple[str, float, float, float | None]], path: Path, title: str, ylabel: str) -> Path:
    """One bar per (label, mean, sd, paper value or None), the paper's value as a marker."""
    fig, ax = report.figure()
    xs = np.arange(len(groups))
    ax.bar(xs, [g[1] for g in groups], yerr=[g[2] for g in groups], capsize=3, color="C0", label="ours (mean ± sd)")
    paper = [(x, g[3]) for x, g in zip(xs, groups) if g[3] is not None]
    if paper:
        ax.plot([p[0] for p in paper], [p[1] for p in paper], "r_", ms=18, mew=2, label="paper")
    ax.set_xticks(xs, [g[0] for g in groups], fontsize=7, rotation=20)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=9)
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=7)
    return savefig(fig, path)


def holds(ok: bool, *values: float) -> bool | None:
    """``ok``, or None (not decided) when a value it compares is NaN (no task done in a cell)."""
    return None if any(isinstance(v, float) and math.isnan(v) for v in values) else bool(ok)


def clearly_more(a: float, b: float, margin: float = 0.05) -> bool | None:
    """``a`` above ``b`` by more than ``margin`` of ``b`` (two runs that behave alike differ by noise only); None
    if either is NaN."""
    return holds(a > b * (1 + margin), a, b)


def claims_text(claims: Sequence[tuple[str, str, str, bool | None]]) -> str:
    from sitl.experiments.formation_common import claims_table
    return claims_table(claims)
