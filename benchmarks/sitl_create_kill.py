"""A Create 2 daemon of a SITL fleet killed (SIGKILL) or frozen (SIGSTOP) mid-drive: simulated and wall seconds
until its body stands still (speed under 1 cm/s), with the daemon's stop guard at its default bound (0.5 s of
wall time).  The fleet is configs/fleets/create2_4.yaml's four Create 2s sent to three far waypoints as processes
at ``--speedup``; robot 4 gets the signal 3 s (simulated) in, while it moves.

    PYTHONPATH=. python benchmarks/sitl_create_kill.py [--signal KILL|STOP] [--runs 3] [--speedup 1]
"""
from __future__ import annotations

import argparse
import math
import os
import signal
import tempfile
import time
from pathlib import Path

import yaml

from sitl import launcher
from sitl.ports import free_udp_base

ROOT = Path(__file__).resolve().parent.parent


def fleet_file(tmp: Path) -> Path:
    data = yaml.safe_load((ROOT / "configs" / "fleets" / "create2_4.yaml").read_text())
    data["world"] = str(ROOT / "configs" / "worlds" / "arena_10m.yaml")
    data["robot"] = str(ROOT / "configs" / "robots" / "create2.yaml")
    base = free_udp_base(len(data["robots"]), start=23000 + os.getpid() % 200 * 40)
    data["base_port"], data["gcs"] = base, f"127.0.0.1:{base}"
    tasks = [{"kind": "goto", "x": x, "y": y, "hold": 1.0} for x, y in ((-4.0, -4.0), (4.0, -4.0), (4.0, 4.0))]
    data["scenario"] = {"type": "mission", "tasks": tasks}
    p = tmp / "fleet.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def once(sig: int, speedup: float, tmp: Path) -> tuple[float, float] | None:
    f = launcher.build(fleet_file(tmp), tmp / f"run{time.monotonic_ns()}")
    st = {"sent": None, "last": None, "still": None}

    def watch(fleet):
        t = fleet.world.t
        x, y, _ = fleet.true_pose(4)
        last, st["last"] = st["last"], (t, x, y)
        if last is None or t <= last[0]:
            return
        speed = math.hypot(x - last[1], y - last[2]) / (t - last[0])
        if st["sent"] is None and t > 3.0 and speed > 0.05:
            os.kill(fleet.robots[4].proc.pid, sig)
            st["sent"] = (t, time.monotonic())
        elif st["sent"] is not None and st["still"] is None and speed < 0.01:
            st["still"] = (t - st["sent"][0], time.monotonic() - st["sent"][1])
        if st["still"] is not None or (st["sent"] and t - st["sent"][0] > 40):
            raise KeyboardInterrupt
    try:
        launcher.run_processes(f, speedup, timeout=120, on_step=watch)
    except KeyboardInterrupt:
        pass
    finally:
        if sig == signal.SIGSTOP and st["sent"]:
            try:
                os.kill(f.robots[4].proc.pid, signal.SIGCONT)
            except ProcessLookupError:
                pass
        f.close()
    return st["still"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--signal", default="KILL", choices=["KILL", "STOP"])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--speedup", type=float, default=1.0)
    args = ap.parse_args()
    sig = signal.Signals[f"SIG{args.signal}"]
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.runs):
            r = once(sig, args.speedup, Path(tmp))
            print(f"SIG{args.signal} at speedup {args.speedup:g}: standstill after "
                  + ("never (40 s)" if r is None else f"{r[0]:.3f} s simulated, {r[1]:.3f} s wall"), flush=True)


if __name__ == "__main__":
    main()
