"""What recording costs a lock-step SITL run: wall and CPU time with and without run.mcap, and the file's size per
robot-minute, measured in one run.

Each fleet runs in lock-step ``--repeats`` times without and with recording, alternating (so a change in the
machine's load hits both alike); the runs are deterministic for the seed, so both kinds end at the same sim time
(checked).  CPU is this process's (every thread: the MCAP writer compresses in Rust); the overhead is the median
with over the median without.  On a machine shared with other jobs those two medians move by +-10 % from load
alone, so the recorded runs also time themselves inside the recording's hooks (:class:`Inside`): that share of
their wall time is the recording's cost, measured in the same run.  Size: MCAP bytes per robot per minute of simulated time, raw MAVLink frames
included (on by default in SITL).

With ``--processes SPEEDUP`` the runs are daemon processes instead (``mrta sitl run`` without ``--lockstep``; the
process-mode tests run so), each daemon recording ``robot_N.mcap`` with raw frames and the launcher ``run.mcap``;
CPU then is every process's (this one's and its ended children's), the size that of every file.

Usage: python benchmarks/recording_cost.py [--fleets create2_4 coalition_6] [--repeats 3] [--processes SPEEDUP]
[--json OUT]
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT)) if str(ROOT) not in sys.path else None

from sitl import launcher  # noqa: E402
from tests.sitl_util import shipped_fleet  # noqa: E402


class Inside:
    """Time spent inside the recording's hooks (wall by perf_counter, CPU by thread_time), measured in the recorded
    run itself: the host's calls into the feed, the operator's side, the link taps and the log tap, opening and
    closing the file."""

    HOOKS = (("runtime.recording.feed", "CoreFeed", "cycle"), ("runtime.recording.feed", "CoreFeed", "frames"),
             ("runtime.recording.feed", "LogTap", "emit"), ("runtime.recording.recorder", "FrameTap", "__call__"),
             ("sitl.recording", "FleetRecording", "__init__"), ("sitl.recording", "FleetRecording", "step"),
             ("sitl.recording", "FleetRecording", "close"))

    def __init__(self):
        import importlib

        self.seconds = 0.0
        self.cpu = 0.0                          # CPU seconds (this thread's) inside the hooks: load moves it less
        self.depth = 0
        self.saved = []
        for mod, cls, name in self.HOOKS:
            klass = getattr(importlib.import_module(mod), cls)
            self.saved.append((klass, name, getattr(klass, name)))
            setattr(klass, name, self._wrap(getattr(klass, name)))

    def _wrap(self, fn):
        def timed(*args, **kwargs):
            if self.depth:                      # nested hooks (a log record inside the feed) count once
                return fn(*args, **kwargs)
            self.depth += 1
            t0, c0 = time.perf_counter(), time.thread_time()
            try:
                return fn(*args, **kwargs)
            finally:
                self.seconds += time.perf_counter() - t0
                self.cpu += time.thread_time() - c0
                self.depth -= 1
        return timed

    def restore(self) -> None:
        for klass, name, fn in self.saved:
            setattr(klass, name, fn)


def _cpu() -> float:
    """CPU seconds of this process and of its children that have ended (the daemon processes)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


def one(fleet: Path, run_dir: Path, record: bool, speedup: float | None = None) -> dict:
    """One run: lock-step, or (``speedup``) one daemon process per robot on a clock that many times real time,
    each recording itself into RUN_DIR/robot_N.mcap as `mrta sitl run` has them do."""
    f = launcher.build(fleet, run_dir)
    inside = Inside() if record and speedup is None else None
    try:
        wall0, cpu0 = time.perf_counter(), _cpu()
        if speedup is None:
            res = launcher.run_lockstep(f, record=record)
        else:
            res = launcher.run_processes(f, speedup, record=record)
    finally:
        f.close()
        wall, cpu = time.perf_counter() - wall0, _cpu() - cpu0
        if inside is not None:
            inside.restore()
    size = sum(p.stat().st_size for p in run_dir.glob("*.mcap")) if record else 0
    return {"wall": wall, "cpu": cpu, "sim": res["sim_time"], "cpu_per_sim": cpu / max(res["sim_time"], 1e-9), "robots": len(f.robots), "bytes": size,
            "goal_met": res["goal_met"], "inside": inside.seconds if inside else 0.0,
            "inside_cpu": inside.cpu if inside else 0.0}


def measure(name: str, repeats: int, tmp: Path, speedup: float | None = None) -> dict:
    fleet = shipped_fleet(tmp, f"{name}.yaml", ports_from=33000)
    runs = {False: [], True: []}
    for k in range(repeats):
        for record in (False, True):
            runs[record].append(one(fleet, tmp / f"{name}_{k}_{int(record)}_{speedup}", record, speedup))
    sims = {round(r["sim"], 1) for rs in runs.values() for r in rs}
    off, on = runs[False], runs[True]
    med = lambda rs, key: statistics.median(r[key] for r in rs)          # noqa: E731
    robot_min = on[0]["robots"] * on[0]["sim"] / 60.0
    return {
        "fleet": name, "robots": on[0]["robots"], "sim_time": on[0]["sim"], "same_sim_time": len(sims) == 1,
        "goal_met": all(r["goal_met"] for rs in runs.values() for r in rs),
        "wall_off": med(off, "wall"), "wall_on": med(on, "wall"), "cpu_off": med(off, "cpu"), "cpu_on": med(on, "cpu"),
        "wall_overhead": med(on, "wall") / med(off, "wall") - 1.0, "cpu_overhead": med(on, "cpu") / med(off, "cpu") - 1.0,
        "inside_share": statistics.median(r["inside"] / r["wall"] for r in on),
        "inside_cpu_share": statistics.median(r["inside_cpu"] / r["cpu"] for r in on),
        "inside_cpu_each": [round(r["inside_cpu"] / r["cpu"], 3) for r in on],
        "mcap_bytes": on[0]["bytes"], "mb_per_robot_minute": on[0]["bytes"] / 1e6 / robot_min,
        "cpu_each": {"off": [round(r["cpu"], 2) for r in off], "on": [round(r["cpu"], 2) for r in on]},
        "sim_each": {"off": [round(r["sim"], 2) for r in off], "on": [round(r["sim"], 2) for r in on]},
        # daemon processes run on a clock, so their runs end at different sim times: CPU per sim second
        "cpu_per_sim_off": med(off, "cpu_per_sim"), "cpu_per_sim_on": med(on, "cpu_per_sim"),
        "cpu_per_sim_overhead": med(on, "cpu_per_sim") / med(off, "cpu_per_sim") - 1.0,
        "wall_each": {"off": [round(r["wall"], 2) for r in off], "on": [round(r["wall"], 2) for r in on]},
        "mode": "lockstep" if speedup is None else f"processes at {speedup:g}x",
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--fleets", nargs="+", default=["create2_4", "coalition_6"])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--processes", type=float, default=None, metavar="SPEEDUP",
                   help="daemon processes on a clock SPEEDUP times real time (each recording robot_N.mcap, as "
                        "`mrta sitl run` does) instead of lock-step; CPU is every process's")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="mrta-rec-bench-") as tmp:
        for name in args.fleets:
            row = measure(name, args.repeats, Path(tmp), args.processes)
            rows.append(row)
            print(f"{name} ({row['mode']}, load average {os.getloadavg()[0]:.1f}): CPU each run without "
                  f"{row['cpu_each']['off']}, with {row['cpu_each']['on']}; wall without {row['wall_each']['off']}, "
                  f"with {row['wall_each']['on']}; sim time without {row['sim_each']['off']}, with "
                  f"{row['sim_each']['on']}; CPU per sim second {row['cpu_per_sim_off']:.3f} -> "
                  f"{row['cpu_per_sim_on']:.3f} ({100 * row['cpu_per_sim_overhead']:+.1f} %); CPU inside the hooks "
                  f"each recorded run (share of its CPU) {row['inside_cpu_each']}", flush=True)
            print(f"{name}: {row['robots']} robots, {row['sim_time']:.1f} s sim (same in every run: "
                  f"{row['same_sim_time']}); wall {row['wall_off']:.2f} -> {row['wall_on']:.2f} s "
                  f"({100 * row['wall_overhead']:+.1f} %), CPU {row['cpu_off']:.2f} -> {row['cpu_on']:.2f} s "
                  f"({100 * row['cpu_overhead']:+.1f} %); inside the recording's hooks "
                  f"{100 * row['inside_share']:.1f} % of the recorded runs' wall time, "
                  f"{100 * row['inside_cpu_share']:.1f} % of their CPU; files {row['mcap_bytes'] / 1e6:.2f} MB = "
                  f"{row['mb_per_robot_minute']:.2f} MB per robot-minute", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
