"""What recording costs a lock-step SITL run: wall and CPU time with and without run.mcap, and the file's size per
robot-minute, measured in one run.

Each fleet runs in lock-step ``--repeats`` times without and with recording, alternating (so a change in the
machine's load hits both alike); the runs are deterministic for the seed, so both kinds end at the same sim time
(checked).  CPU is this process's (every thread: the MCAP writer compresses in Rust); the overhead is the median
with over the median without.  On a machine shared with other jobs those two medians move by +-10 % from load
alone, so the recorded runs also time themselves inside the recording's hooks (:class:`Inside`): that share of
their wall time is the recording's cost, measured in the same run.  Size: MCAP bytes per robot per minute of simulated time, raw MAVLink frames
included (on by default in SITL).

Usage: python benchmarks/recording_cost.py [--fleets create2_4 coalition_6] [--repeats 3] [--json OUT]
"""
from __future__ import annotations

import argparse
import json
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
    """Time spent inside the recording's hooks (perf_counter), measured in the recorded run itself: the host's
    calls into the feed, the operator's side, the link taps and the log tap, opening and closing the file."""

    HOOKS = (("runtime.recording.feed", "CoreFeed", "cycle"), ("runtime.recording.feed", "CoreFeed", "frames"),
             ("runtime.recording.feed", "LogTap", "emit"), ("runtime.recording.recorder", "Recorder", "frame"),
             ("sitl.recording", "FleetRecording", "__init__"), ("sitl.recording", "FleetRecording", "step"),
             ("sitl.recording", "FleetRecording", "close"))

    def __init__(self):
        import importlib

        self.seconds = 0.0
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
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                self.seconds += time.perf_counter() - t0
                self.depth -= 1
        return timed

    def restore(self) -> None:
        for klass, name, fn in self.saved:
            setattr(klass, name, fn)


def one(fleet: Path, run_dir: Path, record: bool) -> dict:
    f = launcher.build(fleet, run_dir)
    inside = Inside() if record else None
    try:
        wall0, cpu0 = time.perf_counter(), time.process_time()
        res = launcher.run_lockstep(f, record=record)
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    finally:
        f.close()
        if inside is not None:
            inside.restore()
    size = (run_dir / "run.mcap").stat().st_size if record else 0
    return {"wall": wall, "cpu": cpu, "sim": res["sim_time"], "robots": len(f.robots), "bytes": size,
            "goal_met": res["goal_met"], "inside": inside.seconds if inside else 0.0}


def measure(name: str, repeats: int, tmp: Path) -> dict:
    fleet = shipped_fleet(tmp, f"{name}.yaml", ports_from=33000)
    runs = {False: [], True: []}
    for k in range(repeats):
        for record in (False, True):
            runs[record].append(one(fleet, tmp / f"{name}_{k}_{int(record)}", record))
    sims = {r["sim"] for rs in runs.values() for r in rs}
    off, on = runs[False], runs[True]
    med = lambda rs, key: statistics.median(r[key] for r in rs)          # noqa: E731
    robot_min = on[0]["robots"] * on[0]["sim"] / 60.0
    return {
        "fleet": name, "robots": on[0]["robots"], "sim_time": on[0]["sim"], "same_sim_time": len(sims) == 1,
        "goal_met": all(r["goal_met"] for rs in runs.values() for r in rs),
        "wall_off": med(off, "wall"), "wall_on": med(on, "wall"), "cpu_off": med(off, "cpu"), "cpu_on": med(on, "cpu"),
        "wall_overhead": med(on, "wall") / med(off, "wall") - 1.0, "cpu_overhead": med(on, "cpu") / med(off, "cpu") - 1.0,
        "inside_share": statistics.median(r["inside"] / r["wall"] for r in on),
        "mcap_bytes": on[0]["bytes"], "mb_per_robot_minute": on[0]["bytes"] / 1e6 / robot_min,
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--fleets", nargs="+", default=["create2_4", "coalition_6"])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="mrta-rec-bench-") as tmp:
        for name in args.fleets:
            row = measure(name, args.repeats, Path(tmp))
            rows.append(row)
            print(f"{name}: {row['robots']} robots, {row['sim_time']:.1f} s sim (same in every run: "
                  f"{row['same_sim_time']}); wall {row['wall_off']:.2f} -> {row['wall_on']:.2f} s "
                  f"({100 * row['wall_overhead']:+.1f} %), CPU {row['cpu_off']:.2f} -> {row['cpu_on']:.2f} s "
                  f"({100 * row['cpu_overhead']:+.1f} %); inside the recording's hooks "
                  f"{100 * row['inside_share']:.1f} % of the recorded runs' wall time; run.mcap {row['mcap_bytes'] / 1e6:.2f} MB = "
                  f"{row['mb_per_robot_minute']:.2f} MB per robot-minute", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
