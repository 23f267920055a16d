"""Time from a daemon's death (SIGKILL) or freeze (SIGSTOP) mid-drive to its body standing still, per base.

Each run: the base's emulator on a kinematic body in this process, the daemon's base loop with its stop guard in a
child (``tests/stop_rig.py``), driving at 0.2 m/s and 0.3 rad/s; the child gets the signal and the wheels are
watched every 5 ms.

    PYTHONPATH=. python benchmarks/base_stop.py [--runs 5] [--base create_pty ...]
"""
from __future__ import annotations

import argparse
import signal
import statistics

from tests.stop_rig import BASES, StopRig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--base", nargs="*", default=list(BASES), choices=BASES)
    args = ap.parse_args()
    print("| base | signal | runs | standstill after, mean / max (s) |")
    print("| --- | --- | --- | --- |")
    for kind in args.base:
        for sig in (signal.SIGKILL, signal.SIGSTOP):
            times = []
            for _ in range(args.runs):
                rig = StopRig(kind)
                try:
                    times.append(rig.standstill_after(sig))
                finally:
                    rig.close()
            ok = [t for t in times if t is not None]
            late = len(times) - len(ok)
            text = f"{statistics.mean(ok):.3f} / {max(ok):.3f}" if ok else "-"
            print(f"| {kind} | {sig.name} | {len(times)} | {text}{f' ({late} never within 10 s)' if late else ''} |",
                  flush=True)


if __name__ == "__main__":
    main()
