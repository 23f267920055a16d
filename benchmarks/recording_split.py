"""Where a recorded lock-step run's recording time goes: the CPU (this thread's) spent in each part of the recording,
each part's own time without what it calls in another part, in the recorded runs of ``--repeats`` alternating runs
without and with recording (the first recorded run, which imports the libraries, is left out).

The parts: ``writer`` (foxglove-sdk's ``log`` of a message through the recorder's ``_log``: the MCAP writer, its
chunks and compression, and the protobuf encoding of an SDK message object), ``feed`` (the core feed's own work:
reading the core's pose, commitments, fleet table, path, sensors), ``pose`` (building the pose, truth and frame
transform messages), ``tap`` (the links' raw frames: held, then written as JSON), ``command``, ``events`` (the JSON
of allocation events, stats, bumpers), ``scene``, ``log``, ``fleet step`` (the SITL host's side), ``check``,
``open/close``.  A part that the tree does not have is left out, so the script runs on an older tree too (run it
from that tree's root).

Each timed call costs about 1.5 us of timer calls (two ``thread_time`` reads, measured with ``--calibrate``), half
of it counted in the part and half in its caller: the parts add up to more than the recording costs untimed.

``--once plain|record``: one lock-step run, nothing timed, without or with recording (the libraries and the
recording's modules imported either way), for an instruction count the machine's load does not move: ``valgrind --tool=cachegrind
--cache-sim=no python benchmarks/recording_split.py --once record``.

Usage: python benchmarks/recording_split.py [--fleet create2_4] [--repeats 3] [--calibrate] [--once plain|record]
"""
from __future__ import annotations

import argparse
import importlib
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path.cwd()
sys.path.insert(0, str(ROOT)) if str(ROOT) not in sys.path else None

R, F, S = "runtime.recording.recorder", "runtime.recording.feed", "sitl.recording"
PARTS = {
    "writer": [(R, "Recorder", "_log")],
    "feed": [(F, "CoreFeed", "cycle"), (F, "CoreFeed", "frames")],
    "pose": [(R, "Recorder", "pose"), (R, "Recorder", "transform"), (R, "Recorder", "transforms")],
    "tap": [(R, "Recorder", "frame"), (R, "FrameTap", "__call__"), (R, "Recorder", "_write_frames")],
    "command": [(R, "Recorder", "command")],
    "path": [(R, "Recorder", "path")],
    "ranges/scan": [(R, "Recorder", "ranges"), (R, "Recorder", "scan")],
    "events": [(R, "Recorder", "event"), (R, "Recorder", "stats"), (R, "Recorder", "bumpers")],
    "scene": [(R, "Recorder", "scene"), (S, "FleetRecording", "_scene")],
    "log": [(R, "Recorder", "text"), (F, "LogTap", "emit")],
    "check": [(R, "Recorder", "check")],
    "fleet step": [(S, "FleetRecording", "step")],
    "open/close": [(S, "FleetRecording", "__init__"), (S, "FleetRecording", "close")],
}


class Split:
    """Each part's own CPU: a stack of the timed calls, a call's time less its timed callees'."""

    def __init__(self):
        self.own = {p: 0.0 for p in PARTS}
        self.calls = {p: 0 for p in PARTS}
        self.stack: list[list] = []
        self.on = False
        for part, hooks in PARTS.items():
            for mod, cls, name in hooks:
                klass = getattr(importlib.import_module(mod), cls, None)
                if klass is not None and name in vars(klass):
                    setattr(klass, name, self._wrap(part, getattr(klass, name)))

    def _wrap(self, part, fn):
        tt, stack = time.thread_time, self.stack

        def timed(*args, **kwargs):
            if not self.on:
                return fn(*args, **kwargs)
            stack.append([tt(), 0.0])
            try:
                return fn(*args, **kwargs)
            finally:
                t0, inner = stack.pop()
                took = tt() - t0
                self.own[part] += took - inner
                self.calls[part] += 1
                if stack:
                    stack[-1][1] += took
        return timed


def calibrate(n: int = 100_000) -> float:
    """CPU a timed call adds (us), of an empty function."""
    s = Split.__new__(Split)
    s.own, s.calls, s.stack, s.on = {"x": 0.0}, {"x": 0}, [], True
    f = s._wrap("x", lambda: None)
    t0 = time.thread_time()
    for _ in range(n):
        f()
    return 1e6 * (time.thread_time() - t0) / n


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--fleet", default="create2_4")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--calibrate", action="store_true", help="also say what a timed call costs")
    p.add_argument("--once", choices=("plain", "record"), default=None,
                   help="one run, nothing timed, without or with recording (for valgrind's instruction count)")
    args = p.parse_args(argv)
    from sitl import launcher
    from tests.sitl_util import shipped_fleet

    if args.once:          # the recording's modules imported with or without it: only the run differs
        import foxglove.mcap  # noqa: F401
        import foxglove.messages  # noqa: F401

        import runtime.recording.feed  # noqa: F401
        import runtime.recording.recorder  # noqa: F401
        import sitl.recording  # noqa: F401

        with tempfile.TemporaryDirectory(prefix="mrta-rec-once-") as tmp:
            f = launcher.build(shipped_fleet(Path(tmp), f"{args.fleet}.yaml", ports_from=33000), Path(tmp) / "run")
            try:
                res = launcher.run_lockstep(f, record=args.once == "record")
            finally:
                f.close()
        print(f"{args.fleet} {args.once}: {res['sim_time']:.2f} s sim")
        return 0

    split = Split()
    cpu = {False: [], True: []}
    with tempfile.TemporaryDirectory(prefix="mrta-rec-split-") as tmp:
        fleet = shipped_fleet(Path(tmp), f"{args.fleet}.yaml", ports_from=33000)
        for k in range(args.repeats + 1):
            for record in (False, True):
                f = launcher.build(fleet, Path(tmp) / f"run_{k}_{int(record)}")
                split.on = record and k > 0
                c0 = time.process_time()
                try:
                    launcher.run_lockstep(f, record=record)
                finally:
                    f.close()
                if k > 0:
                    cpu[record].append(time.process_time() - c0)
    off = statistics.median(cpu[False])
    n = args.repeats
    total = sum(split.own.values()) / n
    print(f"{args.fleet}: CPU each run without {[round(c, 2) for c in cpu[False]]}, with "
          f"{[round(c, 2) for c in cpu[True]]} s; the parts together {total:.3f} s a recorded run = "
          f"{100 * total / off:.1f} % of the median unrecorded run ({off:.2f} s)")
    for part in sorted(PARTS, key=split.own.get, reverse=True):
        if split.calls[part]:
            print(f"  {part:11s} {split.own[part] / n:6.3f} s {100 * split.own[part] / n / off:4.1f} %  "
                  f"{split.calls[part] // n:6d} calls")
    if args.calibrate:
        print(f"a timed call adds {calibrate():.2f} us of CPU")
    return 0


if __name__ == "__main__":
    sys.exit(main())
