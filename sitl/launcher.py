"""`mrta sitl run FLEET`: the pybullet world, emulated devices, one daemon per robot, and an operator.

Like ArduPilot SITL: the daemons are the same program a robot runs; only their configs differ.  The
launcher writes one robot config per robot (from the robot's template: pty paths, UDP ports, start pose)
into a run directory, and a JSON manifest describing every robot's devices and ports so other software can
attach.  The scenario's tasks reach the fleet the way an operator's do: mission uploads over MAVLink from
the ground-station port (:mod:`sitl.operator`), so a daemon cannot tell SITL from a real fleet.

Run modes: one daemon process per robot on a clock ``speedup`` times real time that the world publishes
(:func:`run_processes`), or, with ``--lockstep``, the daemons inside this process on a simulated clock,
deterministic for a given seed (:func:`run_lockstep`).  Either way the run ends when the scenario's goal is
met, at the timeout, or on Ctrl-C; the summary, ``trace.json`` and ``run.png`` (paths, tasks, who did which
and when) go into the run directory.
"""
from __future__ import annotations

import argparse
import json
import math
import logging
import os
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
from runtime.control import compiled
from runtime.log import get_logger
from sitl import fleet_config as FC
from sitl.ports import INSTANCE_STRIDE, check_instance

log = get_logger("sitl")
MAX_LAG = 0.25      # s of sim time the world may trail the speedup clock before the clock slips
SETTLE = 1.0        # s the goal must hold before the run ends
PREROLL_ROUNDS = 200


WITHDRAWN_AT = (500.0, 500.0)     # m: where a withdrawn robot's body is put, far outside any arena


@dataclass
class SimRobot:
    id: int
    body: object
    base_dev: object
    gps_dev: object
    udp_port: int
    config_path: Path
    base_type: str
    radius: float                       # m, the body's footprint (for the run's picture)
    sensor_devs: list = field(default_factory=list)     # (type, emulator) of its sensors: entries but the GPS
    proc: subprocess.Popen | None = None
    daemon: object = None
    exit_reported: bool = False


@dataclass
class Fleet:
    """World, devices and (optionally) daemons of one SITL run."""
    fleet: FC.FleetConfig
    world_cfg: C.WorldConfig
    robots: dict[int, SimRobot]
    world: object
    run_dir: Path
    manifest_path: Path
    scenario: object = None
    key: bytes | None = None            # the fleet's signing key (None: an unsigned fleet)
    fresh_key: Path | None = None       # a key made for this run: removed by close() unless keep_key
    key_path: Path | None = None        # the file the robots read the key from (fresh, --key or the fleet's)
    device_period: float = 0.005
    events: list[str] = field(default_factory=list)
    device_hook: object = None          # called with the sim time after every device service
    withdrawn: set[int] = field(default_factory=set)     # robots taken out of the arena
    segments: object = None             # the Zenoh routers (comms.transport zenoh): a sitl.segments.Segments
    stopped: set[int] = field(default_factory=set)       # robots whose lock-step daemon no longer runs (killed)
    held: dict = field(default_factory=dict)             # robot id -> its MAVLink port's socket, bound since the check

    # -------------------------------------------------------------- ports
    def take_socket(self, rid: int):
        """Robot ``rid``'s MAVLink socket, bound since the port check, for its daemon (None once taken)."""
        return self.held.pop(rid, None)

    def release_ports(self) -> None:
        """Unbind the ports still held (devices only: the user's own daemons bind them)."""
        for sock in self.held.values():
            sock.close()
        self.held.clear()

    # -------------------------------------------------------------- devices
    def service_devices(self) -> None:
        t = self.world.t
        for r in self.robots.values():
            r.base_dev.service(t)
            r.gps_dev.service(t)
            for _, dev in r.sensor_devs:
                dev.service(t)

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

    def withdraw(self, rid: int) -> None:
        """Take robot ``rid``'s body out of the arena, as a person carries a failed robot away (paper 000
        §6.4): it no longer blocks or shows on the others' sensors, and the run's trace ends its track."""
        self.robots[rid].body.place(WITHDRAWN_AT[0] + 5.0 * rid, WITHDRAWN_AT[1], 0.0)
        self.withdrawn.add(rid)

    def close(self, keep_key: bool = False) -> None:
        self.release_ports()
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
            for dev in (r.base_dev, r.gps_dev, *(d for _, d in r.sensor_devs)):
                if hasattr(dev, "close"):
                    dev.close()
        self.world.close()
        if self.segments is not None:
            self.segments.close()
        if self.fresh_key is not None and not keep_key:
            self.fresh_key.unlink(missing_ok=True)


def claim_ports(fleet: FC.FleetConfig, instance: int = 0) -> tuple[FC.FleetConfig, dict]:
    """The fleet moved to instance ``instance`` (its ground-station and robot ports + INSTANCE_STRIDE x N), and
    every robot's MAVLink port bound: ``(fleet, {robot id: its bound UDP socket})``.  The sockets are held from
    this check on and handed to the daemons (:meth:`Fleet.take_socket`), so no program that starts meanwhile can
    take a robot's port; a port busy now is an InputError naming it (another fleet runs)."""
    import dataclasses
    import socket

    check_instance(fleet, instance)
    host, gcs_port = C.parse_hostport(fleet.gcs, fleet.source, "gcs")
    shift = INSTANCE_STRIDE * instance
    fleet = dataclasses.replace(fleet, base_port=fleet.base_port + shift, gcs=f"{host}:{gcs_port + shift}")
    held: dict[int, socket.socket] = {}
    for r in fleet.robots:
        port = fleet.base_port + r.id
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            s.bind(("127.0.0.1", port))
        except OSError as e:
            s.close()
            for other in held.values():
                other.close()
            raise C.ConfigError(fleet.source, "base_port",
                                f"free UDP ports: 127.0.0.1:{port} (robot {r.id}'s MAVLink port) is in use "
                                f"({e.strerror}); another fleet? run this one with --instance N") from None
        held[r.id] = s
    return fleet, held


def build(fleet_path: str | Path, run_dir: str | Path | None = None, manifest: str | Path | None = None,
          seed: int | None = None, signing: bool = True, method: str | None = None,
          speedup: float | None = None, instance: int = 0, peer_loss: float | None = None,
          loss_burst: float | None = None, key: str | Path | None = None,
          unsigned_gcs: list[str] | None = None, transport: str = "udp", segments: int = 1) -> Fleet:
    """Load the fleet, hold its robots' ports, build the world and devices, write robot configs and the manifest.
    ``peer_loss`` and ``loss_burst`` (else the fleet's, else each template's) become every robot's
    ``comms.peer_loss`` and ``comms.loss_burst``.  The fleet signs with the key file ``key`` (``--key``), else the
    fleet's ``signing_key``, else (``signing``) a fresh key in the run directory, removed by :meth:`Fleet.close`
    unless kept.  ``unsigned_gcs`` (``--unsigned-gcs``; networks in CIDR form) becomes every robot's
    ``comms.unsigned_gcs``.  ``transport`` ``zenoh`` starts ``segments`` linked Zenoh routers on loopback and points
    each robot at its segment's (robot configs then name their peers by id only: no addresses)."""
    fleet, held = claim_ports(FC.load_fleet(fleet_path), instance)
    try:
        return _build(fleet, held, run_dir, manifest, seed, signing, method, speedup, peer_loss, loss_burst, key,
                      unsigned_gcs, transport, segments, instance)
    except BaseException:
        for sock in held.values():
            sock.close()
        raise


def _build(fleet, held, run_dir, manifest, seed, signing, method, speedup, peer_loss, loss_burst, key,
           unsigned_gcs, transport, segments, instance) -> Fleet:
    from sitl import scenarios

    world_cfg = C.load_world(fleet.world)
    templates = {}
    for r in fleet.robots:
        path = fleet.template(r.id)
        if path not in templates:
            C.load_robot(path)          # validate the template itself, naming its own file on error
            templates[path] = yaml.safe_load(Path(path).read_text()) or {}
    if method is not None:
        from runtime.allocation import registry
        if method not in registry.METHODS:
            raise C.ConfigError("--method", "", f"one of {'|'.join(registry.METHODS)}", method)

    from runtime.comms import dialect
    dialect.load()      # the MAVLink bindings (and their bytecode, in a fresh tree) before any device serves: a first
    #                     compile of them in this process later would hold the emulators' threads for seconds
    from sitl.devices.nmea_gps import NmeaGpsDevice      # pybullet only once the configs are good
    from sitl.devices.registry import body_kind, make_device, make_sensor_device
    from sitl.world import World
    seed = fleet.seed if seed is None else seed
    run_dir = Path(run_dir or tempfile.mkdtemp(prefix="mrta-sitl-"))
    run_dir.mkdir(parents=True, exist_ok=True)
    key_path, fresh_key = fleet_key(fleet, key, signing, run_dir)
    key = None
    if key_path is not None:
        from runtime.comms.link import load_key
        key = load_key(key_path)

    zenoh = None
    if transport == "zenoh":
        from sitl.segments import Segments
        zenoh = Segments(segments, [r.id for r in fleet.robots], fleet=f"sitl{instance}")
    world = World(world_cfg, seed=seed)
    robots: dict[int, SimRobot] = {}
    ports = {r.id: fleet.base_port + r.id for r in fleet.robots}
    for r in fleet.robots:
        template = dict(templates[fleet.template(r.id)])
        robot_cfg = C.load_robot(fleet.template(r.id))
        base_cfg = robot_cfg.base
        body = world.add_body(r.id, r.start, body_kind(base_cfg))
        base_dev = make_device(base_cfg, body, r.id)
        # every robot has the world's GPS emulator; its other sensors: entries their twins
        gps_dev = NmeaGpsDevice(body, world_cfg.datum, noise_sigma=fleet.gps_noise, seed=seed * 1000 + r.id,
                                robot_id=r.id)
        entries = [e for e in robot_cfg.sensors if e.type != "nmea_gps"]
        sensor_devs = [(e.type, make_sensor_device(e, body, r.id)) for e in entries]
        # the daemon is given the GPS only when its template has one (paper 000's foraging robots have none:
        # odometry only); the emulator runs either way, for the manifest and for --devices-only clients
        template.pop("gps", None)
        template["sensors"] = [{**C.to_dict(e), **dev.endpoint()} for e, (_, dev) in zip(entries, sensor_devs)] + \
            ([{"type": "nmea_gps", **gps_dev.endpoint()}] if robot_cfg.has_gps else [])
        if not robot_cfg.has_gps:
            template["gps"] = {"enabled": False}
        overrides = {
            "robot": {"id": r.id, "name": f"{template.get('robot', {}).get('name', 'robot')}-{r.id}"},
            "base": base_dev.endpoint(),
            "localization": {"initial_pose": list(r.start)},
            "comms": {"listen": f"127.0.0.1:{ports[r.id]}", "gcs": fleet.gcs,
                      "peers": [{"id": o, "address": f"127.0.0.1:{p}"} for o, p in ports.items() if o != r.id],
                      "signing_key": str(key_path) if key_path else None,
                      "loss_seed": seed * 1000 + r.id},          # the run's seed, as the GPS noise's
            "planning": {"map": str(Path(fleet.world).resolve())},
            "datum": C.to_dict(world_cfg.datum),
        }
        for name, given in (("peer_loss", peer_loss), ("loss_burst", loss_burst)):
            value = getattr(fleet, name) if given is None else given
            if value is not None:
                overrides["comms"][name] = value
        if unsigned_gcs:
            overrides["comms"]["unsigned_gcs"] = list(unsigned_gcs)
        if zenoh is not None:
            overrides["comms"].update(zenoh.comms(r.id))
        if method:
            overrides["allocation"] = {"method": method}
        data = C.deep_merge(template, overrides)
        if method and (template.get("allocation") or {}).get("method") not in (None, method):
            data["allocation"] = {"method": method}        # the template's options belong to its own method
        _anchor_paths(data, Path(fleet.template(r.id)).parent)
        cfg_path = run_dir / f"robot_{r.id}.yaml"
        cfg_path.write_text(yaml.safe_dump(data, sort_keys=False))
        C.load_robot(cfg_path)   # what we wrote must load
        robots[r.id] = SimRobot(r.id, body, base_dev, gps_dev, ports[r.id], cfg_path, base_cfg.type,
                                float(body.radius), sensor_devs)

    manifest_path = Path(manifest) if manifest else run_dir / "manifest.json"
    out = Fleet(fleet, world_cfg, robots, world, run_dir, manifest_path, key=key,
                fresh_key=key_path if fresh_key else None, key_path=key_path, held=held, segments=zenoh)
    out.scenario = scenarios.module(fleet.scenario.type).Scenario(fleet, world_cfg)
    if hasattr(out.scenario, "build"):
        out.scenario.build(world)                 # the scenario's own bodies (unmapped obstacles)
    write_manifest(out, speedup if speedup is not None else fleet.speedup, seed, key_path)
    return out


def fleet_key(fleet: FC.FleetConfig, key: str | Path | None, signing: bool, run_dir: Path) -> tuple[Path | None, bool]:
    """(the key file the robots sign with, whether it was made for this run): ``key`` (``--key``, checked: an
    InputError naming it if it is missing or not a key), else the fleet's ``signing_key`` (resolved against the
    fleet file), else with ``signing`` a fresh key in ``run_dir``; (None, False) for an unsigned fleet: without
    ``signing`` (``--no-signing``) the fleet's ``signing_key`` is not used either (the command line wins)."""
    from runtime.comms.link import load_key, new_key

    if key is not None:
        load_key(key, "--key")
        return Path(key).resolve(), False
    if not signing:
        return None, False
    if fleet.signing_key:
        return Path(fleet.signing_key).resolve(), False
    if signing:
        return new_key(run_dir / "fleet.key"), True
    return None, False


TEMPLATE_PATHS = (("allocation", "model"),)      # file paths a robot template may give relative to itself


def _anchor_paths(data: dict, template_dir: Path) -> None:
    """The template's relative file paths made absolute: the robot config is written elsewhere (the run dir)."""
    for section, key in TEMPLATE_PATHS:
        value = (data.get(section) or {}).get(key)
        if isinstance(value, str) and value and not Path(value).is_absolute():
            data[section][key] = str((template_dir / value).resolve())


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
                "base": {"type": r.base_type, **r.base_dev.endpoint()},
                "gps": {"protocol": "nmea0183", "device": r.gps_dev.path, "baudrate": 9600},
                "sensors": [{"type": kind, **d.endpoint()} for kind, d in r.sensor_devs],
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

def finish(f: Fleet, op, ended: str, picture: bool = True) -> dict:
    """The scenario's summary, the verdict, the run's events, and the trace and its picture in the run directory.
    ``ended``: why the run stopped ("goal", "timeout", "stopped", "refused", "unreachable"); ``picture``: False
    leaves run.png out (``res["picture"]`` None), for callers that read only the result (0.3-1 s of CPU a run)."""
    from sitl.operator import RunView

    view = RunView(op)
    res = f.scenario.summary(view)
    res["sim_time"] = f.world.t
    res["lost"] = sorted(op.dead)
    res["goal_met"], res["verdict"] = verdict(f.scenario, view, ended, f.world.t, op.dead, op.refused())
    res["events"] = list(f.events)
    try:
        op.trace.write(f.run_dir / "trace.json")
        res["picture"] = None
        if picture:
            from sitl.run_plot import plot_run
            res["picture"] = str(plot_run(op.trace, f.run_dir / "run.png"))
    except Exception as exc:          # a picture must never cost the run its summary
        log.warning("run picture not drawn: %s", exc)
        res["picture"] = None
    return res


def verdict(scenario, view, ended: str, t: float, dead, refused: list[str]) -> tuple[bool, str]:
    """(goal met, the verdict line) of a run that ``ended`` ("goal", "timeout", "stopped", "refused",
    "unreachable") at sim time ``t``: "goal met" only over work done; a run with no work to judge it by (nothing
    handed in, or all of it withdrawn by a clear: the scenario's ``idle(view)`` line) says so and is not met."""
    short = scenario.shortfall(view)
    if short is None:
        return True, "goal met"
    idle = getattr(scenario, "idle", None)
    if idle is not None and ended in ("stopped", "timeout") and short == idle(view):
        head, parts = "", [short]                  # no work: the run is judged by nothing, and says so
    else:
        why = {"timeout": f"timeout after {t:.0f} s", "stopped": "stopped by the operator",
               "refused": "; ".join(refused), "unreachable": scenario.unreachable(view) or "unreachable"}
        head, parts = "goal not met: ", [why.get(ended, ended), short]
    if dead:
        parts.append("robot(s) " + ", ".join(map(str, sorted(dead))) + " died")
    return False, head + "; ".join(parts)


def print_summary(f: Fleet, res: dict, out=sys.stdout) -> None:
    f.scenario.print_summary(res, out)
    for e in res["events"]:
        print(f"event: {e}", file=out)
    if res.get("picture"):
        print(f"picture: {res['picture']}", file=out)
    if res.get("recording"):
        print(f"recording: {res['recording']}", file=out)
    print(f"verdict: {res['verdict']}", file=out)


# ---------------------------------------------------------------------- run modes

def _check(f: Fleet, op, now: float, since: float | None, wait: bool = False) -> tuple[str | None, float | None]:
    """Whether the run ends now, and why: "refused" (a hand-over was refused), "unreachable" (the goal cannot be
    met any more), "goal" (met for SETTLE seconds; never while ``wait``ing for an operator)."""
    from sitl.operator import RunView

    view = RunView(op)
    if op.refused():
        return "refused", since
    if f.scenario.unreachable(view):
        return "unreachable", since
    if not wait and f.scenario.goal(view):
        since = now if since is None else since
        return ("goal" if now - since > SETTLE else None), since
    return None, None


def scenario_actions(f: Fleet, op, now: float, kill) -> None:
    """What a reacting scenario asks for after an operator poll: new hand-overs go to the operator, kills to
    ``kill(robot)`` (a withdrawal also takes the body out of the arena)."""
    from sitl.operator import RunView
    from sitl.scenarios.base import Handover

    hook = getattr(f.scenario, "on_poll", None)
    if hook is None:
        return
    for action in hook(RunView(op), now):
        if isinstance(action, Handover):
            op.handovers.append(action)
        elif action[0] in ("kill", "withdraw") and action[1] in f.robots:
            what = "killed" if action[0] == "kill" else "killed and withdrawn"
            f.events.append(f"robot {action[1]} {what} by the scenario at {now:.1f} s")
            log.warning("scenario: robot %d %s at %.1f s", action[1], what, now)
            kill(action[1])
            if action[0] == "withdraw":
                f.withdraw(action[1])


class Lockstep:
    """The daemons inside this process on a simulated clock, with the operator: :meth:`step` runs one control
    cycle of physics, daemons and operator.  Deterministic for a given seed."""

    def __init__(self, f: Fleet, record: str | Path | None = None, live: tuple[str, int] | None = None):
        from runtime.daemon import Daemon
        from sitl.operator import Operator

        self.f = f
        self.clock = SimClock(f.world.t)
        self.daemons = {}
        for r in f.robots.values():
            r.daemon = self.daemons[r.id] = Daemon(C.load_robot(r.config_path), listen_socket=f.take_socket(r.id))
            r.daemon.open(self.clock.now())
        self.recording = open_recording(f, record, live)
        if self.recording is not None:
            self.recording.attach(self.daemons)
        self.op = Operator(f)
        self.period = min(d.period for d in self.daemons.values())
        self.stopped = f.stopped                # robots whose daemon no longer runs (killed), kept on the Fleet
        self._preroll()

    def _preroll(self) -> None:
        """Hand-overs due at the start complete before the first cycle, as if the operator had uploaded while
        the robots were booting: the daemons only answer messages until then."""
        f, op = self.f, self.op
        for _ in range(PREROLL_ROUNDS):
            if not op.due(f.world.t):
                break
            op.poll(f.world.t)
            self._service()
        for _ in range(3):                 # the table copies spread to every robot
            op.poll(f.world.t)
            self._service()

    def _service(self) -> None:
        for rid, d in self.daemons.items():
            if rid not in self.stopped:
                d.service(self.clock.now())

    def step(self) -> None:
        f = self.f
        f.advance_to(f.world.t + self.period)
        self.clock.sleep_until(f.world.t)
        if self.recording is not None:
            self.recording.rec.stamp(f.world.t)
        for rid, d in self.daemons.items():
            if rid not in self.stopped:
                d.step(self.clock.now())
        self.op.poll(f.world.t)
        scenario_actions(f, self.op, f.world.t, self.kill)
        self.op.record(f.world.t)
        if self.recording is not None:
            self.recording.step(f.world.t, self.op)

    def kill(self, rid: int) -> None:
        """Robot ``rid``'s daemon dies: it neither steps nor answers from now on (its body stays)."""
        self.stopped.add(rid)
        self.daemons[rid].link.close()
        self.op.robot_died(rid, self.f.world.t)

    def close(self) -> None:
        try:
            if self.recording is not None:
                self.recording.close(self.op.trace)
        finally:
            self.op.close()


def open_recording(f: Fleet, record, live: tuple[str, int] | None):
    """The run's recording (``record``: a path, True for RUN_DIR/run.mcap, None or False for none) and live view,
    or None; without foxglove-sdk (the [record] extra) a warning and no recording, unless the live view was asked
    for (then an InputError)."""
    from runtime.errors import InputError

    if not record and live is None:
        return None
    from runtime.recording.recorder import RecordingUnavailable
    from sitl.recording import FleetRecording

    path = f.run_dir / "run.mcap" if record is True else Path(record) if record else None
    try:
        return FleetRecording(f, path, live)
    except RecordingUnavailable as exc:
        if live is not None:
            raise InputError(f"--live: {exc}") from None
        log.warning("%s: the run is not recorded", exc)
        return None
    except OSError as exc:
        raise InputError(f"{path}: expected a recording file that can be written ({exc.strerror or exc})") from None


def run_lockstep(f: Fleet, timeout: float | None = None, progress=None, on_step=None, record=False,
                 live: tuple[str, int] | None = None, picture: bool = True) -> dict:
    """Daemons in this process on a simulated clock: deterministic for a given seed.
    ``on_step(fleet)`` is called after every control cycle (tests attach observers there).  ``record``: the run's
    MCAP (True: RUN_DIR/run.mcap, as `mrta sitl run` asks; a path; False: none, the default for tests and
    experiments); ``live``: serve it over the Foxglove WebSocket protocol; ``picture``: as :func:`finish`'s."""
    compiled.enable()           # many robots faster than real time in one process: the executive's compiled kernels
    run = Lockstep(f, record, live)
    timeout = timeout or f.fleet.timeout
    wait = getattr(f.fleet.scenario, "wait", False)
    since, next_progress, ended = None, 0.0, None
    try:
        while f.world.t < timeout and ended is None:
            run.step()
            if on_step is not None:
                on_step(f)
            ended, since = _check(f, run.op, f.world.t, since, wait)
            if progress and f.world.t >= next_progress:
                progress(f, run.op)
                next_progress += 5.0
        res = finish(f, run.op, ended or "timeout", picture)
    finally:
        run.close()
    if run.recording is not None and run.recording.path is not None:
        res["recording"] = str(run.recording.path)
    return res


def daemon_stats(f: Fleet) -> dict[int, dict]:
    """The last status snapshot each daemon process wrote (``--stats``)."""
    out = {}
    for rid in f.robots:
        try:
            out[rid] = json.loads((f.run_dir / f"robot_{rid}.stats.json").read_text())
        except (OSError, ValueError):
            pass
    return out


def run_processes(f: Fleet, speedup: float, timeout: float | None = None, progress=None, stop_flag=None,
                  linger: float = 0.0, on_step=None, wait: bool | None = None, record=False,
                  live: tuple[str, int] | None = None) -> dict:
    """One daemon process per robot on a clock ``speedup`` times real time.  ``record``: the world's and the
    operator's side in RUN_DIR/run.mcap and each daemon's own recording in RUN_DIR/robot_N.mcap; ``live``: the
    world's and the operator's side served over the Foxglove WebSocket protocol, with every daemon's channels
    (each streams them to the launcher, ``--live-relay``: :mod:`runtime.recording.relay`).

    ``linger``: wall seconds to keep everything running after the goal is met; the result then holds each
    daemon's CPU share over that idle window (``idle_cpu_share``, 1.0 = one core).  ``wait``: run until the
    timeout or ``stop_flag()`` even when the goal is met (a fleet serving an operator)."""
    from sitl.operator import Operator

    clock_file = f.run_dir / "clock"
    for stale in f.run_dir.glob("clock*"):
        stale.unlink()
    recording = open_recording(f, record, live)
    relay = recording.serve_relay() if recording is not None and live is not None else None
    for r in f.robots.values():
        cmd = [sys.executable, "-m", "runtime.cli", *_verbosity(), "daemon", str(r.config_path),
               "--speedup", repr(speedup), "--clock-file", str(clock_file),
               "--stats", str(f.run_dir / f"robot_{r.id}.stats.json")]
        if record:
            cmd += ["--record", str(f.run_dir / f"robot_{r.id}.mcap"), "--record-mavlink"]
        if relay is not None:            # one live view for the whole fleet: each daemon streams its channels here
            cmd += ["--live-relay", f"{relay[0]}:{relay[1]}"]
        sock = f.take_socket(r.id)              # the port held since the check: the daemon inherits it, bound
        if sock is not None:
            cmd += ["--listen-fd", str(sock.fileno())]
        try:
            with open(f.run_dir / f"robot_{r.id}.log", "w") as log_fh:
                r.proc = subprocess.Popen(cmd, stdout=log_fh, stderr=subprocess.STDOUT, preexec_fn=_die_with_parent,
                                          pass_fds=() if sock is None else (sock.fileno(),))
        finally:
            if sock is not None:
                sock.close()                    # the daemon has its own descriptor of it now
    op = Operator(f)
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
    # the world is the time master: it steps towards wall time x speedup and publishes how far it got; catching
    # up on a lag, it runs up to MAX_LAG ahead of what a daemon has read, which no device may take for a silent master
    for r in f.robots.values():
        allow = getattr(r.base_dev, "allow_clock_lag", None)
        if allow is not None:
            allow(MAX_LAG)
    clock = ScaledClock(speedup)
    clock.epoch -= f.world.t / speedup          # sim time continues from where the world is
    publisher = ClockPublisher(str(clock_file), f.world.t)
    f.device_hook = publisher.publish
    timeout = timeout or f.fleet.timeout
    wait = getattr(f.fleet.scenario, "wait", False) if wait is None else wait
    since, next_progress, next_record = None, 0.0, 0.0
    max_lag, slips, idle_from, ended = 0.0, 0, None, None
    t_start, wall_start = f.world.t, time.monotonic()
    try:
        while True:
            if stop_flag and stop_flag():
                ended = ended or "stopped"
                break
            if f.world.t >= timeout:
                ended = ended or "timeout"
                break
            target = clock.now()
            f.advance_to(min(target, f.world.t + 0.05))      # bounded chunks: keep watching the fleet
            lag = target - f.world.t
            max_lag = max(max_lag, lag)
            if lag > MAX_LAG:            # the machine cannot hold this speedup: slip rather than sprint later
                clock.epoch += (lag - MAX_LAG) / speedup
                slips += 1
            now = f.world.t
            op.poll(now)
            if recording is not None:
                recording.poll()
            scenario_actions(f, op, now, lambda rid: _kill_process(f, rid))
            if now >= next_record:
                op.record(now)
                next_record = now + 0.05
                if recording is not None:
                    recording.step(now, op)
            if on_step is not None:
                on_step(f)
            for r in f.robots.values():
                code = r.proc.poll() if r.proc else None
                if code is not None and not r.exit_reported:
                    r.exit_reported = True
                    msg = f"robot {r.id} daemon exited with code {code} (log: {f.run_dir / f'robot_{r.id}.log'})"
                    f.events.append(msg)
                    log.error(msg)
                    op.robot_died(r.id, now)
            if idle_from is not None:
                if time.monotonic() - idle_from[0] >= linger:
                    break
            else:
                ended, since = _check(f, op, now, since, wait)
                if ended is not None:
                    if ended != "goal" or linger <= 0:
                        break
                    idle_from = (time.monotonic(), {r.id: _cpu_seconds(r.proc.pid) for r in f.robots.values()})
            if progress and now >= next_progress:
                progress(f, op)
                next_progress += 5.0
            time.sleep(0.002)
        f.device_hook = None
        publisher.close()
        res = finish(f, op, ended or "timeout")
    finally:
        try:
            if recording is not None:
                recording.close(op.trace)
        finally:
            op.close()
    if recording is not None and recording.path is not None:
        res["recording"] = str(recording.path)
    res["world_max_lag"] = max_lag
    res["clock_slips"] = slips
    if slips:
        res["events"].append(slip_warning(speedup, slips, f.world.t - t_start, time.monotonic() - wall_start))
    if idle_from is not None:
        wall = time.monotonic() - idle_from[0]
        res["idle_cpu_share"] = {rid: (_cpu_seconds(f.robots[rid].proc.pid) - c0) / wall
                                 for rid, c0 in idle_from[1].items()}
    return res


def slip_warning(speedup: float, slips: int, sim: float, wall: float) -> str:
    """The run's event when the world fell behind its clock: what it means for the run and what to do."""
    achieved = sim / wall if wall > 0 else speedup
    suggest = max(0.5, math.floor(min(achieved, speedup) * 0.8 * 2) / 2)
    return (f"this machine could not hold the {speedup:g}x clock: the world fell more than {MAX_LAG} s behind it "
            f"{slips} times and ran at {achieved:.2g}x on average. The daemons, short of CPU too, then step less often "
            f"than their control rate in sim time, so robots react later than on real hardware (closer calls, "
            f"longer stops) and the run is less faithful; run it again with --speedup {suggest:g} "
            f"or lower, or with --lockstep")


def _verbosity() -> list[str]:
    """The daemons log as much as the launcher does (``mrta -v sitl run``: INFO in every robot's log)."""
    level = logging.getLogger().getEffectiveLevel()
    return ["-vv"] if level <= logging.DEBUG else ["-v"] if level <= logging.INFO else []


def _kill_process(f: Fleet, rid: int) -> None:
    """SIGKILL robot ``rid``'s daemon (the loop then reports its exit, as it would a crash)."""
    proc = f.robots[rid].proc
    if proc is not None and proc.poll() is None:
        proc.kill()


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


def _progress(f: Fleet, op) -> None:
    """One line every 5 s of sim time: who reports, who holds a task, the fleet's tasks, then the scenario's own
    progress where it has one (formation: positions held and reached, as its tasks are never done), else how many
    tasks are done (done-then-cleared ones too) and withdrawn."""
    from runtime.messages import CLEARED, DONE, WITHDRAWN
    from sitl.operator import RunView

    live = op.live_robots()
    busy = sum(1 for rid in live if op.gcs.robots[rid].tasks)
    states = [r.state for r in op.gcs.table.values()]
    done = sum(s in (DONE, CLEARED) for s in states)
    withdrawn = sum(s == WITHDRAWN for s in states)
    own = getattr(f.scenario, "progress", None)
    line = (f"[t={f.world.t:6.1f} s] robots reporting {len(live)}/{len(f.robots)}, holding a task {busy}, "
            f"fleet tasks {len(states)}")
    if own is not None:                 # its tasks may never be done (formation positions): its own words
        line += f", {own(RunView(op))}"
    else:
        line += f" ({done} done{f', {withdrawn} withdrawn' if withdrawn else ''})"
    print(line, flush=True)


def register(sub: argparse._SubParsersAction) -> None:
    from runtime.allocation import registry
    from sitl.run_args import MAX_INSTANCE, fleet_range

    p = sub.add_parser("sitl", help="software-in-the-loop simulation")
    s = p.add_subparsers(dest="sitl_cmd", metavar="SUBCOMMAND", required=True)
    r = s.add_parser("run", help="run a fleet: world, emulated devices, one daemon per robot, an operator")
    r.add_argument("fleet", help="fleet config YAML, or the name of a shipped fleet (create2_4, ...)")
    r.add_argument("--manifest", default=None, help="write the ports manifest here (JSON)")
    r.add_argument("--run-dir", default=None, help="where robot configs, logs, trace and picture go (default: a temp dir)")
    r.add_argument("--seed", type=int, default=None, help="override the fleet's seed (%d..%d)" % fleet_range("seed"))
    r.add_argument("--speedup", type=float, default=None,
                   help="sim seconds per wall second (%g..%g)" % fleet_range("speedup"))
    r.add_argument("--lockstep", action="store_true", help="daemons in-process on a simulated clock")
    r.add_argument("--devices-only", action="store_true", help="world and devices only, no daemons")
    r.add_argument("--instance", type=int, default=0, metavar="N",
                   help=f"run beside other fleets: every port + {INSTANCE_STRIDE} x N (ground station and robots; "
                        f"N 0..{MAX_INSTANCE})")
    r.add_argument("--no-signing", dest="signing", action="store_false",
                   help="an unsigned fleet (default: every frame signed with a fresh fleet key, or the fleet's "
                        "signing_key)")
    r.add_argument("--key", default=None, metavar="FILE",
                   help="sign with this fleet key file (mrta key FILE [--passphrase P]) instead of a fresh key or "
                        "the fleet's signing_key; it is left in place after the run")
    r.add_argument("--unsigned-gcs", action="append", default=None, metavar="CIDR",
                   help="every robot takes unsigned ground-station frames from this network (repeatable; e.g. "
                        "127.0.0.1/32 for a station that cannot sign; peers still sign)")
    r.add_argument("--keep-key", action="store_true",
                   help="keep the run's fresh fleet key (RUN_DIR/fleet.key) for a ground station after the run")
    r.add_argument("--method", choices=registry.names(), default=None, help="allocation method")
    r.add_argument("--timeout", type=float, default=None,
                   help="sim seconds before giving up (%g..%g)" % fleet_range("timeout"))
    r.add_argument("--peer-loss", type=float, default=None, metavar="P",
                   help="every robot drops this share of its datagrams to each peer at random, a lossy radio "
                        "(%g..%g; default: the fleet's peer_loss, else none)" % fleet_range("peer_loss"))
    r.add_argument("--loss-burst", type=float, default=None, metavar="S",
                   help="with --peer-loss: the losses come in spells of this mean length in seconds, as fading "
                        "brings them (%g..%g; default: the fleet's loss_burst, else 0: each on its own)"
                        % fleet_range("loss_burst"))
    r.add_argument("--transport", choices=("udp", "zenoh"), default="udp",
                   help="what carries the robots' peer frames: udp (default) or zenoh through routers on loopback "
                        "(needs the [zenoh] extra)")
    r.add_argument("--segments", type=int, default=1, metavar="K",
                   help="with --transport zenoh: K linked routers, the robots split among them (default 1)")
    r.add_argument("--json", default=None, help="write the result here as JSON")
    r.add_argument("--no-record", dest="record", action="store_false",
                   help="write no recording (default: RUN_DIR/run.mcap, and each daemon process its "
                        "RUN_DIR/robot_N.mcap)")
    from runtime.recording.options import add_live
    add_live(r, "the fleet's recording channels")
    r.set_defaults(func=_main)


def _main(args) -> int:
    from sitl import run_args

    from runtime.recording.options import live_address

    args.fleet = str(FC.find_fleet(args.fleet))      # a file, or a shipped fleet by name
    run_args.check(args)          # every option, before the world is built
    live = live_address(args.live)
    f = build(args.fleet, args.run_dir, args.manifest, args.seed, args.signing, args.method, args.speedup,
              args.instance, args.peer_loss, args.loss_burst, args.key, args.unsigned_gcs,
              transport=args.transport, segments=args.segments)
    speedup = args.speedup or f.fleet.speedup
    stop = {"flag": False}

    def _stop(signum, frame):
        stop["flag"] = True

    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    print(f"SITL: {len(f.robots)} robots, manifest {f.manifest_path}, run dir {f.run_dir}", flush=True)
    try:
        if args.devices_only:
            f.release_ports()                   # your own daemons bind the robots' ports
            print("devices only: Ctrl-C to stop", flush=True)
            clock = ScaledClock(speedup)
            while not stop["flag"]:
                f.advance_to(clock.now())
                time.sleep(0.002)
            return 0
        if getattr(f.fleet.scenario, "wait", False):
            key = f" --key {f.key_path}" if f.key else ""
            print(f"waiting for an operator: upload missions to the robots' MAVLink ports in {f.manifest_path} "
                  f"(mrta mission upload 127.0.0.1:{f.robots[min(f.robots)].udp_port} FILE{key}); Ctrl-C to stop",
                  flush=True)
        if live is not None:
            print(f"live: Foxglove WebSocket on ws://{live[0]}:{live[1]} (layout: docs/foxglove_layout.json)",
                  flush=True)
        if args.lockstep:
            res = run_lockstep(f, args.timeout, progress=_progress, record=args.record, live=live)
        else:
            res = run_processes(f, speedup, args.timeout, progress=_progress, stop_flag=lambda: stop["flag"],
                                record=args.record, live=live)
    finally:
        f.close(keep_key=args.keep_key)
    print_summary(f, res)
    if args.json:
        try:
            Path(args.json).write_text(json.dumps(res, indent=2, default=str))
        except OSError as exc:
            raise C.ConfigError("--json", "", f"a file that can be written ({exc.strerror})", args.json) from None
    if not res["goal_met"]:
        print(f"mrta: {res['verdict']}", file=sys.stderr)
        return 1
    return 0
