"""What the live relay (``mrta daemon --live-relay``, a process fleet's ``--live``) adds to a daemon's recorder: CPU
per message logged with and without the stream to a launcher, in one process (the launcher's end drains the stream
in a thread, as its loop would), 20,000 cycles of a pose, a wheel command and an allocation event.

Usage: python benchmarks/recording_relay_cost.py [--cycles 20000] [--repeats 2]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT)) if str(ROOT) not in sys.path else None

from runtime.recording.recorder import Recorder  # noqa: E402
from runtime.recording.relay import RelayServer  # noqa: E402


def run(tmp: Path, relay: bool, cycles: int) -> tuple[float, int, int]:
    """(CPU s of the recording thread, messages relayed, messages the sender dropped)."""
    launcher = Recorder(None)
    server = RelayServer(launcher) if relay else None
    rec = Recorder(tmp / f"robot_{int(relay)}_{time.monotonic_ns()}.mcap",
                   relay=server.address if relay else None, robot_id=1)
    stop = threading.Event()

    def drain():
        while not stop.is_set():
            server.poll()
            time.sleep(0.002)
    th = threading.Thread(target=drain) if relay else None
    if th:
        th.start()
    c0 = time.thread_time()
    for k in range(cycles):
        t = 0.05 * k
        rec.pose(1, t, (0.001 * k, 0.0, 0.01 * k))
        rec.command(1, t, 0.2, 0.1)
        rec.event(t, 1, "sent", "Bid", 65537, (1,), {"cost": 0.5})
        rec.check()
    cpu = time.thread_time() - c0
    dropped = rec.relay.dropped if rec.relay else 0
    rec.close()
    stop.set()
    if th:
        th.join()
    n = 0
    if server:
        server.close()
        n = server.messages
    launcher.close()
    return cpu, n, dropped


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cycles", type=int, default=20000)
    p.add_argument("--repeats", type=int, default=2)
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="mrta-relay-bench-") as tmp:
        for _ in range(args.repeats):
            for relay in (False, True):
                cpu, n, dropped = run(Path(tmp), relay, args.cycles)
                per = cpu / (3 * args.cycles) * 1e6
                print(f"{'with the relay' if relay else 'file only':14}: {cpu:.3f} s CPU for {3 * args.cycles} messages, "
                      f"{per:.2f} us each" + (f"; relayed {n}, dropped by the sender {dropped}" if relay else ""),
                      flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
