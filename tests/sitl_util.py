"""Helpers for SITL tests: shipped fleet configs on free ports, and a stock pymavlink ground station."""
from __future__ import annotations

import os
import time
from pathlib import Path

import yaml

os.environ.setdefault("MAVLINK20", "1")       # as MAVProxy does (--mav20, its default): MAVLink 2 frames
from pymavlink import mavutil  # noqa: E402

from sitl.ports import free_udp_base

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"



def port_block(start: int = 21000) -> int:
    """Where this test process looks for free UDP ports: each pytest-xdist worker from its own block.  A block
    found free is released before the fleet binds it, so two workers searching the same range could both take it."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    n = int(worker[2:]) if worker.startswith("gw") and worker[2:].isdigit() else 0
    return start + 2500 * (n % 12)


def shipped_fleet(tmp_path: Path, name: str, ports_from: int | None = None, **changes) -> Path:
    """A copy of configs/fleets/NAME with absolute paths and a block of free UDP ports (the first found from
    ``ports_from``, default this test process's block); ``changes`` set fleet keys."""
    src = CONFIGS / "fleets" / name
    data = yaml.safe_load(src.read_text())
    for key in ("world", "robot"):
        data[key] = str((src.parent / data[key]).resolve())
    for r in data["robots"]:
        if r.get("robot"):
            r["robot"] = str((src.parent / r["robot"]).resolve())
    base = free_udp_base(len(data["robots"]), start=port_block() if ports_from is None else ports_from)
    data["base_port"], data["gcs"] = base, f"127.0.0.1:{base}"
    data.update(changes)
    path = tmp_path / f"fleet_{name}"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def worker_fleet(tmp_path: Path, name: str, seed: int, **changes) -> Path:
    """:func:`shipped_fleet` with the fleet's ``seed`` set, for one of several processes building fleets at once
    (a benchmark's workers): its ports are searched from a start of its own (by seed and process), so two workers
    do not find the same free block."""
    return shipped_fleet(tmp_path, name, ports_from=30000 + (seed * 31 + os.getpid()) % 250 * 101, seed=seed,
                         **changes)


def robot_template(tmp_path: Path, src: Path, name: str, **allocation) -> Path:
    """A copy of the robot template ``src`` with ``allocation`` options set, its relative paths anchored as the
    launcher anchors them, written to ``tmp_path/name``."""
    from sitl.launcher import _anchor_paths

    data = yaml.safe_load(Path(src).read_text())
    _anchor_paths(data, Path(src).parent)
    data.setdefault("allocation", {}).update(allocation)
    out = tmp_path / name
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    return out


def devices_only(fleet: Path, tmp_path: Path) -> tuple:
    """``mrta sitl run FLEET --devices-only --speedup 1`` (the world and the emulated devices, no daemons, real
    time) started as a process: (the process, its manifest's robots) once the manifest is written.  Stop it with
    SIGINT."""
    import json
    import subprocess
    import sys

    manifest = tmp_path / "manifest.json"
    proc = subprocess.Popen([sys.executable, "-m", "runtime.cli", "sitl", "run", str(fleet), "--devices-only",
                             "--speedup", "1", "--manifest", str(manifest), "--run-dir", str(tmp_path / "run")],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    deadline = time.monotonic() + 60
    while not manifest.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            raise AssertionError(f"no manifest: {proc.communicate()[0]}")
        time.sleep(0.05)
    return proc, json.loads(manifest.read_text())["robots"]


def lockstep_run(fleet_path: Path, run_dir: Path, read=lambda f: None, on_step=None):
    """Build the fleet at ``fleet_path``, run it in lock-step to its end (goal, timeout, ...), and return (the
    run's result, ``read(fleet)`` taken before the daemons close)."""
    from sitl import launcher

    f = launcher.build(fleet_path, run_dir)
    try:
        res = launcher.run_lockstep(f, on_step=on_step, picture=False)
        return res, read(f)
    finally:
        f.close()


class StockGcs:
    """pymavlink's own connection to one robot's MAVLink port (udpout, as MAVProxy's --master=udpout does):
    requests go out from its socket and the robot answers to where they came from."""

    def __init__(self, port: int, system: int, key: bytes | None = None, link_id: int = 0):
        self.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190,
                                               dialect="common")
        if key is not None:                       # a signed fleet: the ground station has the fleet key too
            # on link id 0, as a station's first connection gets from pymavlink: pymavlink's own count goes up with
            # every connection this process made before (test order), and at 2 it is the SITL operator's stream
            self.conn.setup_signing(key, sign_outgoing=True, link_id=link_id)
        self.system = system
        self.mav = self.conn.mav
        self.got: list = []
        self.pending: list = []
        self.resends = 0            # requests sent again because nothing answered (stock_upload)
    def heartbeat(self) -> None:
        self.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def drain(self) -> list:
        """What a previous :meth:`wait` left over, then every message waiting on the socket."""
        out = []
        while (m := self.conn.recv_match(blocking=False)) is not None:
            if m.get_type() != "BAD_DATA":
                out.append(m)
        self.got += out
        out, self.pending = self.pending + out, []
        return out

    def wait(self, pred, timeout: float, step=None) -> list:
        """Messages until one satisfies ``pred`` (returned last) or ``timeout`` wall seconds; ``step()`` is called
        between polls (a lock-step test advances the fleet there)."""
        seen, t0 = [], time.monotonic()
        while time.monotonic() - t0 < timeout:
            batch = self.drain()
            for k, m in enumerate(batch):
                if pred(m):
                    self.pending = batch[k + 1:]      # the rest of the batch: the next wait sees it first
                    return seen + batch[:k + 1]
            seen += batch
            if step is not None:
                step()
            else:
                time.sleep(0.002)
        return seen

    def close(self) -> None:
        self.conn.close()
