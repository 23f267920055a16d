"""SITL capacity for 4 and 10 robots, measured in one run:

* the world's stepping rate alone (physics only, no devices or daemons), as steps/s and real-time factor;
* the highest --speedup at which every daemon keeps its control deadlines (no cycle a whole period
  late) and the simulator keeps up with the clock, trying 1, 2, 4, ... until one fails;
* each daemon's CPU share (1.0 = one core) at idle: fleet settled, daemons still running at speedup 1.

Usage: python benchmarks/sitl_speedup.py [--robots 4 10] [--max-speedup 32]
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT)) if str(ROOT) not in sys.path else None

from runtime import config as C  # noqa: E402
from sitl import fleet_config as FC  # noqa: E402
from sitl import launcher  # noqa: E402
from sitl.ports import free_udp_base  # noqa: E402
from sitl.world import World  # noqa: E402

FLEETS = {4: ROOT / "configs/fleets/create2_4.yaml", 10: ROOT / "configs/fleets/create2_10.yaml"}


def fleet_file(tmp: Path, n: int, idle: bool = False) -> Path:
    src = FLEETS[n]
    data = yaml.safe_load(src.read_text())
    data["world"] = str((src.parent / data["world"]).resolve())
    data["robot"] = str((src.parent / data["robot"]).resolve())
    base = free_udp_base(len(data["robots"]), start=31000, stride=113)
    data["base_port"], data["gcs"] = base, f"127.0.0.1:{base}"
    if idle:   # formation = where the robots stand: they settle at once and idle
        data["scenario"]["positions"] = [r["start"][:2] for r in data["robots"]]
    p = tmp / f"fleet{n}{'_idle' if idle else ''}.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def world_rate(n: int, seconds: float = 20.0) -> dict:
    fleet = FC.load_fleet(FLEETS[n])
    world = World(C.load_world(fleet.world), seed=1)
    try:
        for r in fleet.robots:
            world.add_body(r.id, r.start, "create2").set_wheel_speeds(0.2, 0.15)
        steps = int(seconds / world.dt)
        t0 = time.process_time()
        for _ in range(steps):
            world.step()
        cpu = time.process_time() - t0
    finally:
        world.close()
    return {"steps_per_s": steps / cpu, "realtime_factor": seconds / cpu}


def fleet_run(n: int, speedup: float, tmp: Path, idle: bool = False, linger: float = 0.0) -> dict:
    run_dir = Path(tempfile.mkdtemp(dir=tmp))
    f = launcher.build(fleet_file(tmp, n, idle), run_dir, speedup=speedup)
    try:
        res = launcher.run_processes(f, speedup, timeout=120, linger=linger)
    finally:
        f.close()
    stats = [json.loads((run_dir / f"robot_{rid}.stats.json").read_text()) for rid in f.robots]
    res["missed"] = sum(s["missed_deadlines"] for s in stats)
    res["cycles"] = sum(s["cycles"] for s in stats)
    res["worst_lateness"] = max(s["worst_lateness"] for s in stats)
    return res


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, nargs="+", default=[4, 10], choices=sorted(FLEETS))
    ap.add_argument("--max-speedup", type=float, default=32.0)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="mrta-bench-"))
    rows = []
    for n in args.robots:
        print(f"--- {n} robots", flush=True)
        wr = world_rate(n)
        print(f"world alone: {wr['steps_per_s']:.0f} steps/s, {wr['realtime_factor']:.1f}x real time", flush=True)
        best, speedup = None, 1.0
        while speedup <= args.max_speedup:
            res = fleet_run(n, speedup, tmp)
            ok = res["valid"] and res["missed"] == 0 and res["clock_slips"] == 0
            print(f"speedup {speedup:5.1f}: valid={res['valid']} missed deadlines {res['missed']}/{res['cycles']} "
                  f"worst lateness {res['worst_lateness'] * 1000:.1f} ms sim, world lag "
                  f"{res['world_max_lag'] * 1000:.0f} ms sim ({res['clock_slips']} slips), sim time {res['sim_time']:.1f} s "
                  f"-> {'keeps up' if ok else 'falls behind'}", flush=True)
            if not ok:
                break
            best = speedup
            speedup *= 2
        idle = fleet_run(n, 1.0, tmp, idle=True, linger=10.0)
        shares = list(idle.get("idle_cpu_share", {}).values())
        print(f"idle daemon CPU share: mean {statistics.mean(shares) * 100:.1f} %, max {max(shares) * 100:.1f} % "
              f"of one core", flush=True)
        rows.append((n, wr, best, shares))
    print("\n| robots | world steps/s | world x real time | highest speedup kept | daemon idle CPU (mean / max) |")
    print("|---|---|---|---|---|")
    for n, wr, best, shares in rows:
        print(f"| {n} | {wr['steps_per_s']:.0f} | {wr['realtime_factor']:.1f} | {best if best else '<1'} | "
              f"{statistics.mean(shares) * 100:.1f} % / {max(shares) * 100:.1f} % |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
