"""`mrta sitl run FLEET`: the pybullet world, emulated devices, and one daemon per robot.

Like ArduPilot SITL: the daemons are the same program a robot runs; only their configs differ.
The launcher writes one robot config per robot (pty paths, UDP ports, start pose, formation) into a
run directory, and a JSON manifest describing every robot's devices and ports so other software can
attach.  It then steps the world on a clock ``speedup`` times real time (shared with the daemon
processes through the system-wide monotonic clock), or, with ``--lockstep``, runs the daemons inside
this process on a simulated clock, deterministic for a given seed.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import secrets
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from runtime import config as C
from runtime.clock import ClockPublisher, ScaledClock, SimClock
from runtime.log import get_logger

log = get_logger("sitl")
MAX_LAG = 0.25      # s of sim time the world may trail the speedup clock before the clock slips


@dataclass
class SimRobot:
    id: int
    body: object
    base_dev: object
    gps_dev: object
    udp_port: int
    config_path: Path
    task_xy: tuple[float, float] | None = None
    proc: subprocess.Popen | None = None
    daemon: object = None
    exit_reported: bool = False


@dataclass
class Fleet:
    """World, devices and (optionally) daemons of one SITL run."""
    fleet: C.FleetConfig
    world_cfg: C.WorldConfig
    robots: dict[int, SimRobot]
    world: object
    run_dir: Path
    manifest_path: Path
    device_period: float = 0.005
    events: list[str] = field(default_factory=list)
    device_hook: object = None          # called with the sim time after every device service

    # -------------------------------------------------------------- devices
    def service_devices(self) -> None:
        t = self.world.t
        for r in self.robots.values():
            r.base_dev.service(t)
            r.gps_dev.service(t)

    def advance_to(self, t_target: float) -> None:
        """Step physics (and service the devices every ``device_period``) up to ``t_target``."""
        world = self.world
        per = max(1, int(round(self.device_period / world.dt)))
        while world.t + 1e-9 < t_target:
            world.step(per)
            self.service_devices()
            if self.device_hook is not None:
                self.device_hook(world.t)

    def true_pose(self, rid: int) -> tuple[float, float, float]:
        return self.robots[rid].body.pose()

    def close(self) -> None:
        for r in self.robots.values():
            if r.daemon is not None:
                r.daemon.close()
            if r.proc is not None and r.proc.poll() is None:
                r.proc.send_signal(signal.SIGTERM)
        for r in self.robots.values():
            if r.proc is not None:
                try:
                    r.proc.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    r.proc.kill()
        for r in self.robots.values():
            for dev in (r.base_dev, r.gps_dev):
                if hasattr(dev, "close"):
                    dev.close()
        self.world.close()


def build(fleet_path: str | Path, run_dir: str | Path | None = None, manifest: str | Path | None = None,
          seed: int | None = None, signing: bool = False, method: str | None = None,
          speedup: float | None = None) -> Fleet:
    """Load the fleet, build the world and devices, write robot configs and the manifest."""
    fleet = C.load_fleet(fleet_path)
    world_cfg = C.load_world(fleet.world)
    template = yaml.safe_load(Path(fleet.robot).read_text()) or {}
    C.load_robot(fleet.robot)   # validate the template itself, naming its own file on error

    from sitl.devices.create_oi import CreateOIDevice      # pybullet only once the configs are good
    from sitl.devices.nmea_gps import NmeaGpsDevice
    from sitl.world import World
    seed = fleet.seed if seed is None else seed
    run_dir = Path(run_dir or tempfile.mkdtemp(prefix="mrta-sitl-"))
    run_dir.mkdir(parents=True, exist_ok=True)
    key_path = None
    if signing or fleet.signing_key:
        key_path = Path(fleet.signing_key) if fleet.signing_key else run_dir / "fleet.key"
        if not fleet.signing_key:
            key_path.write_text(secrets.token_hex(32) + "\n")
            os.chmod(key_path, 0o600)

    world = World(world_cfg, seed=seed)
    robots: dict[int, SimRobot] = {}
    ports = {r.id: fleet.base_port + r.id for r in fleet.robots}
    initiator = min(ports)
    model = template.get("base", {}).get("model", "create2")
    for r in fleet.robots:
        body = world.add_create2(r.id, r.start)
        base_dev = CreateOIDevice(body, model=model, robot_id=r.id)
        gps_dev = NmeaGpsDevice(body, world_cfg.datum, noise_sigma=fleet.gps_noise, seed=seed * 1000 + r.id,
                                robot_id=r.id)
        overrides = {
            "robot": {"id": r.id, "name": f"{template.get('robot', {}).get('name', 'robot')}-{r.id}"},
            "base": {"port": base_dev.path},
            "gps": {"port": gps_dev.path, "enabled": True},
            "localization": {"initial_pose": list(r.start)},
            "comms": {"listen": f"127.0.0.1:{ports[r.id]}", "gcs": fleet.gcs,
                      "peers": [{"id": o, "address": f"127.0.0.1:{p}"} for o, p in ports.items() if o != r.id],
                      "signing_key": str(key_path) if key_path else None},
            "allocation": {"formation": [list(xy) for xy in fleet.formation], "initiator": r.id == initiator},
            "planning": {"map": str(Path(fleet.world).resolve())},
            "datum": C.to_dict(world_cfg.datum),
        }
        if method:
            overrides["allocation"]["method"] = method
        data = C.deep_merge(template, overrides)
        cfg_path = run_dir / f"robot_{r.id}.yaml"
        cfg_path.write_text(yaml.safe_dump(data, sort_keys=False))
        C.load_robot(cfg_path)   # what we wrote must load
        robots[r.id] = SimRobot(r.id, body, base_dev, gps_dev, ports[r.id], cfg_path)

    manifest_path = Path(manifest) if manifest else run_dir / "manifest.json"
    out = Fleet(fleet, world_cfg, robots, world, run_dir, manifest_path)
    write_manifest(out, speedup if speedup is not None else fleet.speedup, seed, key_path)
    return out


def write_manifest(f: Fleet, speedup: float, seed: int, key_path: Path | None) -> None:
    data = {
        "fleet": f.fleet.source,
        "world": f.fleet.world,
        "run_dir": str(f.run_dir),
        "seed": seed,
        "speedup": speedup,
        "ground_station": f.fleet.gcs,
        "signing_key": str(key_path) if key_path else None,
        "robots": [
            {
                "id": r.id, "system_id": r.id, "component_id": 1,
                "base": {"protocol": "create_oi", "device": r.base_dev.path, "baudrate": 115200},
                "gps": {"protocol": "nmea0183", "device": r.gps_dev.path, "baudrate": 9600},
                "mavlink_udp": f"127.0.0.1:{r.udp_port}",
                "config": str(r.config_path),
                "start": list(next(x.start for x in f.fleet.robots if x.id == r.id)),
            }
            for r in f.robots.values()
        ],
    }
    f.manifest_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = f.manifest_path.with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=2))
    os.replace(tmp, f.manifest_path)


# ---------------------------------------------------------------------- results

def summarise(f: Fleet, assignment: dict[int, int | None]) -> dict:
    """Assignment, its straight-line global cost beside the Hungarian optimum, final errors."""
    from scipy.optimize import linear_sum_assignment

    starts = {r.id: r.start for r in f.fleet.robots}
    ids = sorted(starts)
    tasks = [tuple(t) for t in f.fleet.formation]
    from runtime.planning.costs import cost_matrix
    # the costs the daemons bid: planned path lengths on the world map from the start poses
    cost = cost_matrix(f.world_cfg, [starts[i][:2] for i in ids], tasks, planner="astar")
    rows, cols = linear_sum_assignment(cost)
    optimum = float(cost[rows, cols].sum())
    held = [assignment.get(i) for i in ids]
    valid = all(t is not None for t in held) and len(set(held)) == len(held)
    total = float(sum(cost[k, t] for k, t in enumerate(held) if t is not None)) if valid else math.nan
    errors = {}
    for k, rid in enumerate(ids):
        x, y, _ = f.true_pose(rid)
        t = held[k]
        errors[rid] = math.hypot(tasks[t][0] - x, tasks[t][1] - y) if t is not None else math.nan
    return {"assignment": {rid: held[k] for k, rid in enumerate(ids)}, "valid": valid, "tasks": tasks,
            "global_cost": total, "optimum": optimum,
            "optimal_assignment": {ids[r]: int(c) for r, c in zip(rows, cols)},
            "final_error": errors, "sim_time": f.world.t, "events": list(f.events)}


def print_summary(res: dict, out=sys.stdout) -> None:
    print("\nrobot  task  position (m)      optimal task  final error (m)", file=out)
    for rid, task in res["assignment"].items():
        err = res["final_error"][rid]
        pos = "-" if task is None else "({:5.2f}, {:5.2f})".format(*res["tasks"][task])
        print(f"{rid:5d}  {'-' if task is None else task:>4}  {pos:16}  {res['optimal_assignment'][rid]:>12}  "
              f"{'-' if math.isnan(err) else f'{err:.3f}':>15}", file=out)
    gap = 100.0 * (res["global_cost"] - res["optimum"]) / res["optimum"] if res["optimum"] > 0 else 0.0
    print(f"\nglobal cost (path lengths from the start poses) {res['global_cost']:.3f} m   "
          f"Hungarian optimum {res['optimum']:.3f} m   "
          f"gap {gap:+.2f} %", file=out)
    print(f"assignment valid: {res['valid']}   sim time {res['sim_time']:.1f} s", file=out)
    for e in res["events"]:
        print(f"event: {e}", file=out)


# ---------------------------------------------------------------------- run modes

def _done(f: Fleet, status: dict[int, dict], tol: float) -> bool:
    if len(status) < len(f.robots):
        return False
    held = [s.get("task") for s in status.values()]
    if None in held or len(set(held)) != len(held):
        return False
    for rid, s in status.items():
        if not s.get("converged"):
            return False
        tx, ty = f.fleet.formation[s["task"]]
        x, y, _ = f.true_pose(rid)
        vx, vy = f.robots[rid].body.velocity()
        if math.hypot(tx - x, ty - y) > tol or math.hypot(vx, vy) > 0.02:
            return False
    return True


def run_lockstep(f: Fleet, timeout: float | None = None, tol: float = 0.2, progress=None, on_step=None) -> dict:
    """Daemons in this process on a simulated clock: deterministic for a given seed.
    ``on_step(fleet)`` is called after every control cycle (tests attach observers there)."""
    from runtime.daemon import Daemon

    clock = SimClock(f.world.t)
    for r in f.robots.values():
        r.daemon = Daemon(C.load_robot(r.config_path))
        r.daemon.open(clock.now())
    period = min(r.daemon.period for r in f.robots.values())
    timeout = timeout or f.fleet.timeout
    settled_since = None
    next_progress = 0.0
    while f.world.t < timeout:
        f.advance_to(f.world.t + period)
        clock.sleep_until(f.world.t)
        for r in f.robots.values():
            r.daemon.step(clock.now())
        if on_step is not None:
            on_step(f)
        status = {r.id: {"task": r.daemon.agent.assignment, "converged": r.daemon.agent.converged}
                  for r in f.robots.values()}
        if _done(f, status, tol):
            settled_since = settled_since if settled_since is not None else f.world.t
            if f.world.t - settled_since > 1.0:
                break
        else:
            settled_since = None
        if progress and f.world.t >= next_progress:
            progress(f, status)
            next_progress += 5.0
    return summarise(f, {r.id: r.daemon.agent.assignment for r in f.robots.values()})


def daemon_stats(f: Fleet) -> dict[int, dict]:
    """The last status snapshot each daemon process wrote (``--stats``)."""
    out = {}
    for rid in f.robots:
        try:
            out[rid] = json.loads((f.run_dir / f"robot_{rid}.stats.json").read_text())
        except (OSError, ValueError):
            pass
    return out


def run_processes(f: Fleet, speedup: float, timeout: float | None = None, tol: float = 0.2,
                  progress=None, stop_flag=None, linger: float = 0.0, on_step=None) -> dict:
    """One daemon process per robot on a clock ``speedup`` times real time.

    ``linger``: wall seconds to keep everything running after the fleet settles; the result then
    holds each daemon's CPU share over that idle window (``idle_cpu_share``, 1.0 = one core)."""
    from runtime.comms.gcs import GroundStation

    gcs = GroundStation(f.fleet.gcs)
    clock_file = f.run_dir / "clock"
    for stale in f.run_dir.glob("clock*"):
        stale.unlink()
    for r in f.robots.values():
        cmd = [sys.executable, "-m", "runtime.cli", "daemon", str(r.config_path),
               "--speedup", repr(speedup), "--clock-file", str(clock_file),
               "--stats", str(f.run_dir / f"robot_{r.id}.stats.json")]
        with open(f.run_dir / f"robot_{r.id}.log", "w") as log_fh:
            r.proc = subprocess.Popen(cmd, stdout=log_fh, stderr=subprocess.STDOUT, preexec_fn=_die_with_parent)
    # start barrier: the sim clock starts once every daemon is built (imports take seconds)
    deadline = time.monotonic() + 120
    while not all((f.run_dir / f"clock.ready.{rid}").exists() for rid in f.robots):
        dead = [r.id for r in f.robots.values() if r.proc.poll() is not None]
        if dead or time.monotonic() > deadline or (stop_flag and stop_flag()):
            for rid in dead:
                f.events.append(f"robot {rid} daemon exited with code {f.robots[rid].proc.returncode} "
                                f"before starting (log: {f.run_dir / f'robot_{rid}.log'})")
            break
        time.sleep(0.02)
    # the world is the time master: it steps towards wall time x speedup and publishes how far it got
    clock = ScaledClock(speedup)
    clock.epoch -= f.world.t / speedup          # sim time continues from where the world is
    publisher = ClockPublisher(str(clock_file), f.world.t)
    f.device_hook = publisher.publish
    timeout = timeout or f.fleet.timeout
    settled_since = None
    next_progress = 0.0
    max_lag = 0.0
    slips = 0
    idle_from = None
    while not (stop_flag and stop_flag()):
        if f.world.t >= timeout:
            f.events.append(f"timeout after {timeout:.0f} s sim time")
            break
        target = clock.now()
        f.advance_to(min(target, f.world.t + 0.05))      # bounded chunks: keep watching the fleet
        lag = target - f.world.t
        max_lag = max(max_lag, lag)
        if lag > MAX_LAG:            # the machine cannot hold this speedup: slip rather than sprint later
            clock.epoch += (lag - MAX_LAG) / speedup
            slips += 1
        now = f.world.t
        gcs.poll()
        if on_step is not None:
            on_step(f)
        for r in f.robots.values():
            code = r.proc.poll() if r.proc else None
            if code is not None and not r.exit_reported:
                r.exit_reported = True
                msg = f"robot {r.id} daemon exited with code {code} (log: {f.run_dir / f'robot_{r.id}.log'})"
                f.events.append(msg)
                log.error(msg)
        status = {rid: s for rid, s in gcs.status().items() if rid in f.robots}
        if idle_from is not None:
            if time.monotonic() - idle_from[0] >= linger:
                break
        elif _done(f, status, tol):
            settled_since = settled_since if settled_since is not None else now
            if now - settled_since > 1.0:
                if linger <= 0:
                    break
                idle_from = (time.monotonic(), {r.id: _cpu_seconds(r.proc.pid) for r in f.robots.values()})
        else:
            settled_since = None
        if progress and now >= next_progress:
            progress(f, status)
            next_progress += 5.0
        time.sleep(0.002)
    gcs.close()
    f.device_hook = None
    publisher.close()
    res = summarise(f, {rid: s.get("task") for rid, s in gcs.status().items()})
    res["world_max_lag"] = max_lag
    res["clock_slips"] = slips
    if slips:
        f.events.append(f"the world fell more than {MAX_LAG} s behind the {speedup:g}x clock {slips} times "
                        f"(the machine cannot hold this speedup)")
    if idle_from is not None:
        wall = time.monotonic() - idle_from[0]
        res["idle_cpu_share"] = {rid: (_cpu_seconds(f.robots[rid].proc.pid) - c0) / wall
                                 for rid, c0 in idle_from[1].items()}
    return res


def _die_with_parent() -> None:
    """In the child before exec: ask Linux to SIGTERM it when the launcher dies, however it dies."""
    try:
        import ctypes
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)   # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass      # not Linux: the daemons' stalled-clock check still ends them


def _cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of a live process (Linux /proc)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return math.nan


def _progress(f: Fleet, status: dict) -> None:
    arrived = 0
    for rid, s in status.items():
        if s.get("task") is not None:
            tx, ty = f.fleet.formation[s["task"]]
            x, y, _ = f.true_pose(rid)
            arrived += math.hypot(tx - x, ty - y) < 0.2
    print(f"[t={f.world.t:6.1f} s] robots reporting {len(status)}/{len(f.robots)}, "
          f"at their positions {arrived}/{len(f.robots)}", flush=True)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sitl", help="software-in-the-loop simulation")
    s = p.add_subparsers(dest="sitl_cmd", metavar="SUBCOMMAND", required=True)
    r = s.add_parser("run", help="run a fleet: world, emulated devices, one daemon per robot")
    r.add_argument("fleet", help="fleet config YAML")
    r.add_argument("--manifest", default=None, help="write the ports manifest here (JSON)")
    r.add_argument("--run-dir", default=None, help="where robot configs and logs go (default: a temp dir)")
    r.add_argument("--seed", type=int, default=None, help="override the fleet's seed")
    r.add_argument("--speedup", type=float, default=None, help="sim seconds per wall second")
    r.add_argument("--lockstep", action="store_true", help="daemons in-process on a simulated clock")
    r.add_argument("--devices-only", action="store_true", help="world and devices only, no daemons")
    r.add_argument("--signing", action="store_true", help="sign MAVLink with a fresh fleet key")
    r.add_argument("--method", choices=("bs", "rtma", "auction"), default=None, help="allocation method")
    r.add_argument("--timeout", type=float, default=None, help="sim seconds before giving up")
    r.add_argument("--json", default=None, help="write the result here as JSON")
    r.set_defaults(func=_main)


def _main(args) -> int:
    f = build(args.fleet, args.run_dir, args.manifest, args.seed, args.signing, args.method, args.speedup)
    speedup = args.speedup or f.fleet.speedup
    stop = {"flag": False}

    def _stop(signum, frame):
        stop["flag"] = True

    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    print(f"SITL: {len(f.robots)} robots, manifest {f.manifest_path}, run dir {f.run_dir}", flush=True)
    try:
        if args.devices_only:
            print("devices only: Ctrl-C to stop", flush=True)
            clock = ScaledClock(speedup)
            while not stop["flag"]:
                f.advance_to(clock.now())
                time.sleep(0.002)
            return 0
        if args.lockstep:
            res = run_lockstep(f, args.timeout, progress=_progress)
        else:
            res = run_processes(f, speedup, args.timeout, progress=_progress, stop_flag=lambda: stop["flag"])
    finally:
        f.close()
    print_summary(res)
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2, default=str))
    return 0 if res["valid"] and not stop["flag"] else 1
