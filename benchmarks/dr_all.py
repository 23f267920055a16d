"""Paper 000 (issue 16) in one run: every speed figure the issue asks for, measured now on this machine.

1. one 3600 s (30,000 tu), 10-robot foraging run with ``dr`` (target: under 30 s of wall time on one core, 120x
   real time), beside the same scenario stepped by pybullet's default settings (benchmarks/foraging_speed.py);
2. the interference model's refit and predict at 120 samples, beside a grid-search refit and scikit-learn's own
   predict (benchmarks/dr_svr.py);
3. the wall time of each full ``mrta experiment dr-*`` reproduction on 2 cores: with ``--run`` each command is run
   here and timed (hours of CPU); without it, the wall time each committed report under results/ recorded, with
   its command line and commit.

    python benchmarks/dr_all.py [--seconds 3600] [--default-seconds 60] [--run]
"""
from __future__ import annotations

import argparse
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REPORTS = {                      # experiment -> (committed report, the command that regenerates it)
    "dr-calibration": ("results/dr-calibration/dr_calibration.md",
                       "mrta experiment dr-calibration --out results/dr-calibration --duration 600 --jobs 2"),
    "dr-table3 (paper's deadline)": ("results/dr-table3-paper-dl/dr_table3.md",
                                     "mrta experiment dr-table3 --seeds 3 --jobs 2 --time-limit 1800"),
    "dr-table3": ("results/dr-table3/dr_table3.md", "mrta experiment dr-table3 --seeds 5 --jobs 2 --deadline 328"),
    "dr-table4": ("results/dr-table4/dr_table4.md",
                  "mrta experiment dr-table4 --seeds 5 --jobs 2 --deadline 328 --time-limit 2400"),
    "dr-table5": ("results/dr-table5/dr_table5.md", "mrta experiment dr-table5 --seeds 8 --jobs 2 --deadline 328"),
    "dr-table3 (late: fastest)": ("results/dr-table3-fastest/dr_table3.md",
                                  "mrta experiment dr-table3 --seeds 5 --jobs 2 --deadline 328 --late fastest "
                                  "--out out/dr-table3-fastest"),
    "dr-table3 (on-line learning)": ("results/dr-table3-online/dr_table3.md",
                                     "mrta experiment dr-table3 --seeds 5 --jobs 2 --deadline 328 --online "
                                     "--out out/dr-table3-online"),
}
WALL = re.compile(r"Command: `([^`]*)` on commit ([0-9a-f+dirty]+): wall time (\d+) s")


def run(cmd: list[str]) -> int:
    print(f"$ {' '.join(cmd)}", flush=True)
    return subprocess.call(cmd, cwd=ROOT)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3600.0, help="simulated s of the 10-robot run (default 3600)")
    ap.add_argument("--default-seconds", type=float, default=60.0, help="simulated s at pybullet's defaults")
    ap.add_argument("--run", action="store_true", help="run every full reproduction now and time it (hours)")
    args = ap.parse_args()
    py = sys.executable
    print("== 1. one 10-robot foraging run with dr, and the same world at pybullet's defaults")
    code = run([py, "benchmarks/foraging_speed.py", "--method", "dr", "--seconds", f"{args.seconds:g}",
                "--default-seconds", f"{args.default_seconds:g}"])
    print("\n== 2. the interference model at 120 samples")
    code |= run([py, "benchmarks/dr_svr.py"])
    print("\n== 3. the full reproductions on 2 cores")
    for name, (report, command) in REPORTS.items():
        if args.run:
            t0 = time.perf_counter()
            rc = run([py, "-m", "runtime.cli", *command.split()[1:]])
            print(f"{name}: wall time {time.perf_counter() - t0:.0f} s (exit {rc}), measured now")
            code |= rc
            continue
        path = ROOT / report
        m = WALL.search(path.read_text()) if path.exists() else None
        if m is None:
            print(f"{name}: no recorded wall time in {report}; run `{command}` (or this script with --run)")
        else:
            print(f"{name}: wall time {m.group(3)} s on 2 cores, recorded in {report} (`{m.group(1)}` at commit "
                  f"{m.group(2)})")
    return code


if __name__ == "__main__":
    sys.exit(main())
