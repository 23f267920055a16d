"""The robot daemon: wiring only.  sense -> allocate -> execute -> command -> report.

One :class:`Daemon` per robot.  It is a polled object: :meth:`Daemon.step` does one control cycle at time
``now`` and never blocks, so the same object runs in its own process against real devices (:func:`run`,
wall or scaled clock) or lock-stepped inside the SITL process (tests, experiments).

Cycle:
1. sense: the base (odometry, bumpers, ranges) and GPS -> EKF pose;
2. allocate: MAVLink from peers -> the fleet node (task table + allocation agent), lost peers, requests
   from ground stations (missions, parameters, commands) -> the agent's messages out;
3. execute: the executive matches executors to the agent's commitments; they and the robot-wide
   behaviours vote in the arbiter -> the command to the base; progress (arrived, done) back to the agent;
4. report: telemetry, the robot's state, and what happened to tasks, to the ground stations.

Every part it wires is chosen by the config through a registry: the base driver (``base.type``), the
allocation method (``allocation.method``), the executor (task kind).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import signal
import time
from dataclasses import dataclass, field
from pathlib import Path

from runtime import config as C
from runtime.clock import Clock, ClockStalled, ScaledClock, SharedClock, WallClock
from runtime.execution import peer_readings
from runtime.log import get_logger


@dataclass
class DaemonStats:
    cycles: int = 0
    missed_deadlines: int = 0      # cycles that started after the next cycle was due
    worst_lateness: float = 0.0    # s (clock time)
    agent_sent: int = 0
    agent_received: int = 0
    peers_lost: list = field(default_factory=list)
    cpu_seconds: float = 0.0
    wall_seconds: float = 0.0


class Daemon:
    def __init__(self, cfg: C.RobotConfig, *, base=None, gps=None, link=None):
        from runtime.allocation import registry
        from runtime.allocation.agent import AgentContext
        from runtime.comms.ground import GroundServices
        from runtime.comms.telemetry import GcsTelemetry
        from runtime.execution.executive import ExecContext, Executive, Tunables
        from runtime.fleet.node import FleetNode
        from runtime.localization.ekf import PoseEKF
        from runtime.localization.enu import geodetic_to_enu
        from runtime.planning.robot_planner import RobotPlanner, TravelEstimator
        from runtime.tasks import Profile

        self.cfg = cfg
        self.id = cfg.robot.id
        self.log = get_logger("daemon", self.id)
        self.stats = DaemonStats()
        self._geodetic_to_enu = geodetic_to_enu
        if base is None:
            from runtime.drivers.registry import open_base
            base = open_base(cfg.base, self.id)
        self.base = base
        if gps is None and cfg.gps.enabled:
            from runtime.drivers.nmea_gps import NmeaGps
            gps = NmeaGps(cfg.gps.port, baudrate=cfg.gps.baudrate, robot_id=self.id)
        self.gps = gps
        if link is None:
            from runtime.comms.link import MavlinkLink, load_key
            key = load_key(cfg.comms.signing_key) if cfg.comms.signing_key else None
            link = MavlinkLink(self.id, cfg.comms.listen, [p.address for p in cfg.comms.peers],
                               cfg.comms.gcs, signing_key=key,
                               heartbeat_timeout=cfg.comms.heartbeat_timeout, peer_loss=cfg.comms.peer_loss,
                               loss_burst=cfg.comms.loss_burst, loss_seed=cfg.comms.loss_seed)
        self.link = link
        self.telemetry = GcsTelemetry(link, self.id, cfg.datum, armed=cfg.robot.armed)
        self.ekf = PoseEKF(cfg.localization, robot_id=self.id)
        if cfg.localization.initial_pose is not None:
            self.ekf.initialise(*cfg.localization.initial_pose)
        radius = float(base.footprint.radius)       # obstacle inflation and avoidance
        c = cfg.control
        self.planner = RobotPlanner.from_config(cfg, radius)
        self.estimator = TravelEstimator(self.planner, Profile(speed=c.cruise_speed, radius=radius), self.pose)
        self.method = registry.method(cfg.allocation.method)
        self.agent = self.method.make(AgentContext(self.id, tuple(p.id for p in cfg.comms.peers), self.estimator,
                                                   cfg.allocation, cfg.base))
        self.node = FleetNode(self.id, self.agent, armed=cfg.robot.armed, peers=[p.id for p in cfg.comms.peers])
        self.executive = Executive(ExecContext(self.planner, Tunables(c.cruise_speed, c.lookahead, c.max_turn_rate,
                                                                      c.goal_tolerance), self.log, radius,
                                               seed=self.id, agent=self.agent, robot_id=self.id))
        self._perceive = getattr(self.agent, "perceive", None)    # agents that read the robot's pose and ranges
        self.ground = GroundServices(self)
        self.period = 1.0 / c.rate
        self._last_step: float | None = None
        self._first_cycle: float | None = None
        self._heard: set[int] = set()            # peers heard at least once
        self._never_heard_reported = False

    # ------------------------------------------------------------------ pose
    def pose(self) -> tuple[float, float, float] | None:
        return self.ekf.pose() if self.ekf.initialised else None

    @property
    def map(self):
        return self.planner.world

    # ------------------------------------------------------------------ lifecycle
    def open(self, now: float) -> None:
        self.base.open(now)
        if self.gps is not None and hasattr(self.gps, "open"):
            self.gps.open(now)
        self.log.info("open: base %s, gps %s, listening %s, allocation %s%s", self.cfg.base.type,
                      self.cfg.gps.port if self.gps else "off", self.cfg.comms.listen, self.method.name,
                      "" if self.node.armed else " (disarmed)")

    def close(self) -> None:
        try:
            self.base.close()
        finally:
            for part in (self.gps, self.link):
                if part is not None and hasattr(part, "close"):
                    part.close()

    # ------------------------------------------------------------------ one cycle
    def step(self, now: float) -> None:
        self.stats.cycles += 1
        dt = 0.0 if self._last_step is None else now - self._last_step
        self._last_step = now
        self._sense(now, dt)
        self._allocate(now)
        self._execute(now)
        self._report(now)

    def service(self, now: float) -> None:
        """Messages only, no control cycle: peers' task tables and ground-station requests (a SITL operator
        hands tasks in before the first cycle this way).  Peer messages for the agent wait for the next step."""
        self._send(self._comms(now, tick=False), now)

    def _sense(self, now: float, dt: float) -> None:
        if dt > 0 and self.ekf.initialised:
            self.ekf.predict(dt)
        if self.base.poll(now):
            odo = self.base.odometry
            if self.ekf.initialised:
                self.ekf.update_odometry(odo.v, odo.w)
        if self.gps is not None:
            for fix in self.gps.poll(now):
                if not fix.valid:
                    continue
                e, n, _ = self._geodetic_to_enu(fix.lat, fix.lon, fix.alt, self.cfg.datum)
                if not self.ekf.initialised:
                    self.ekf.initialise(e, n, None)
                else:
                    self.ekf.update_gps(e, n, self.cfg.localization.gps_sigma)

    def _velocity(self) -> tuple[float, float]:
        if not self.ekf.initialised:
            return (0.0, 0.0)
        x, y, th = self.ekf.pose()
        v = self.ekf.x[3]
        return (float(v * math.cos(th)), float(v * math.sin(th)))

    def _comms(self, now: float, tick: bool = True) -> list:
        pose = self.pose()
        node = self.node
        node.begin(None if pose is None else (pose[0], pose[1]))
        out = []
        held = getattr(self, "_held_back", [])
        self._held_back = []
        for msg in held + self.link.poll(now):
            if not tick and _for_agent(msg):
                self._held_back.append(msg)           # service(): the agent hears it at the next step
                continue
            self.stats.agent_received += 1
            out += node.on_message(msg, now)
        if tick:
            for lost in self.link.peers_lost(now):
                self.stats.peers_lost.append(lost)
                self.log.warning("peer %d lost (no heartbeat for %.1f s): re-auctioning its work",
                                 lost, self.cfg.comms.heartbeat_timeout)
                out += node.on_peer_lost(lost, now)
            for lost in self._never_heard(now):
                self.stats.peers_lost.append(lost)
                self.log.warning("peer %d never heard in %.1f s (comms.startup_grace): treating it as lost",
                                 lost, self.cfg.comms.startup_grace)
                out += node.on_peer_lost(lost, now)
        out += self.ground.serve(now)
        if tick:
            out += node.tick(now)
        return out

    def _allocate(self, now: float) -> None:
        if self._perceive is not None:
            self._perceive(self.pose(), getattr(self.base.sensors, "ranges", ()), now)
        self._send(self._comms(now), now)

    def _send(self, out: list, now: float) -> None:
        if out:
            self.stats.agent_sent += len(out)
            self.link.send_agent(out, now)

    def _never_heard(self, now: float) -> list[int]:
        """Configured peers not heard once within ``comms.startup_grace`` of the first cycle, reported once:
        the link only times out peers it has heard, and a robot that never came up must not hold the
        allocation back (the epsilon auction waits for every live peer's rung).  If it turns up later, its
        first message makes it live again."""
        if self._never_heard_reported:
            return []
        if self._first_cycle is None:
            self._first_cycle = now
        self._heard.update(getattr(self.link, "peers_alive", ()))
        if now - self._first_cycle < self.cfg.comms.startup_grace:
            return []
        self._never_heard_reported = True
        return sorted(p.id for p in self.cfg.comms.peers if p.id not in self._heard)

    def _execute(self, now: float) -> None:
        """Executors for the agent's commitments vote in the arbiter; the command goes to the base (zero when
        disarmed); their progress goes back to the agent."""
        ex = self.executive
        ex.sync(self.agent.commitments if self.node.armed else (), now)
        ex.make_way = self.node.armed
        pose, sensors = self.pose(), self.base.sensors
        ex.peers = () if pose is None or self.base.ranging or not ex.idle else \
            peer_readings.readings(pose, self.node.positions, now, ex.ctx.radius)    # idle, no range sensors
        (v, w), progress = ex.step(pose, sensors, now)
        self.base.set_velocity(v, w, now)
        out = []
        for p in progress:
            out += self.node.on_progress(p, now)
        self._send(out, now)

    def _report(self, now: float) -> None:
        commitments = self.agent.commitments
        self.telemetry.armed = self.node.armed
        self.telemetry.tick(now, self.pose(), self._velocity(), self.base.sensors,
                            commitments[0].task_id if commitments else None)
        self.ground.report(now)

    def snapshot(self) -> dict:
        pose = self.pose()
        s = self.stats
        p = self.planner.stats
        return {
            "robot": self.id, "pose": pose, "state": self.node.state,
            "tasks": [c.task_id for c in self.agent.commitments],
            "converged": bool(self.agent.converged), "arrived": self.executive.arrived,
            "cycles": s.cycles, "missed_deadlines": s.missed_deadlines,
            "worst_lateness": s.worst_lateness, "agent_sent": s.agent_sent,
            "agent_received": s.agent_received, "peers_lost": s.peers_lost,
            "cpu_seconds": s.cpu_seconds, "wall_seconds": s.wall_seconds,
            "base": vars(self.base.stats) if hasattr(self.base, "stats") else {},
            "link": self.link.counters.as_dict() if hasattr(self.link, "counters") else {},
            "gps_rejected": getattr(self.ekf, "gps_rejected", 0),
            "relocalised": self.ekf.stats.relocalised,     # the pose filter gave up its position and heading
            "made_way": self.executive.made_way,           # idle cycles spent moving off for another robot
            "plan_fallbacks": p.plan_fallbacks, "plan_failures": p.plan_failures, "bid_fallbacks": p.bid_fallbacks,
            "table": len(self.node.table.entries),
            "fleet_dropped": dict(self.node.dropped),
            "agent_dropped": _drops(self.agent),
        }


def _drops(agent) -> dict:
    """What the allocation agent dropped, by reason (a family without reasons: its total)."""
    d = getattr(agent, "dropped", {})
    return dict(d) if isinstance(d, dict) else {"dropped": d}


def _for_agent(msg) -> bool:
    from runtime.fleet.messages import FLEET_MESSAGES
    return not isinstance(msg, FLEET_MESSAGES)


# ---------------------------------------------------------------------- process main loop

class _Stop(BaseException):
    """SIGTERM or SIGINT arrived: leave the loop wherever it is, then stop the motors.  A BaseException, as
    KeyboardInterrupt is: the signal can land inside any ``except Exception`` (every parser loop has one, to count
    what it drops), which must not swallow it."""


def run(daemon: Daemon, clock: Clock, duration: float | None = None, stats_path: str | None = None) -> int:
    """Run ``daemon`` at its control rate until ``duration`` (clock seconds) or SIGTERM/SIGINT; 0, or 3 when the
    base's device vanished.  Whatever ends the loop (a signal, an exception, a lost device), the base is told to
    stop and the final status snapshot is written."""
    from runtime.drivers.base import DeviceLost

    def _stop(signum, frame):
        raise _Stop(signal.Signals(signum).name)

    before = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    t0 = clock.now()
    wall0, cpu0 = time.monotonic(), time.process_time()
    next_t = t0
    last_dump = t0
    code = 0
    try:
        daemon.open(t0)
        while duration is None or clock.now() - t0 < duration:
            now = clock.now()
            late = now - next_t
            if late > daemon.period:       # whole periods late: every cycle that should have run is missed
                daemon.stats.missed_deadlines += int(late // daemon.period)
                next_t = now
            daemon.stats.worst_lateness = max(daemon.stats.worst_lateness, late)
            daemon.step(now)
            next_t += daemon.period
            if stats_path and now - last_dump > 1.0:
                last_dump = now
                daemon.stats.cpu_seconds = time.process_time() - cpu0
                daemon.stats.wall_seconds = time.monotonic() - wall0
                _dump(stats_path, daemon.snapshot())
            try:
                clock.sleep_until(next_t)
            except ClockStalled as exc:
                daemon.log.error("%s: stopping", exc)
                break
    except _Stop as exc:
        daemon.log.info("%s: stopping", exc)
    except DeviceLost as exc:
        daemon.log.error("%s: stopping (the base cannot be told to stop any more)", exc)
        code = 3
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)     # a second signal must not cut the clean-up short
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        daemon.close()
        daemon.stats.cpu_seconds = time.process_time() - cpu0
        daemon.stats.wall_seconds = time.monotonic() - wall0
        if stats_path:
            _dump(stats_path, daemon.snapshot())
        daemon.log.info("stopped after %d cycles, %d missed deadlines", daemon.stats.cycles,
                        daemon.stats.missed_deadlines)
        for s, handler in before.items():      # ignored signals would be inherited by every later child process
            signal.signal(s, handler)
    return code


def _dump(path: str, data: dict) -> None:
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w") as fh:
        json.dump(data, fh, default=str)
    os.replace(tmp, path)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("daemon", help="run one robot's daemon from its robot config")
    p.add_argument("config", help="robot config YAML")
    p.add_argument("--check", action="store_true",
                   help="run every check start-up runs (addresses, peers, map, signing key, base options) without "
                        "opening a device or a socket, then exit: 0 ok, 2 with one line saying what is wrong")
    p.add_argument("--speedup", type=float, default=None,
                   help="SITL only: run on a scaled clock this many times faster than real time")
    p.add_argument("--epoch", type=float, default=None,
                   help="SITL only: monotonic-clock epoch shared with the simulator")
    p.add_argument("--clock-file", default=None,
                   help="SITL only: when built, write FILE.ready.ID, wait for FILE, then take the "
                        "simulator's time from it")
    p.add_argument("--duration", type=float, default=None, help="stop after this many (clock) seconds")
    p.add_argument("--stats", default=None, help="write a JSON status snapshot here every second")
    p.set_defaults(func=_main)


def _wait_for_clock(path: str, robot_id: int, timeout: float = 120.0) -> None:
    """SITL start barrier: say we are built, then wait for the simulator to publish its clock."""
    try:
        Path(f"{path}.ready.{robot_id}").touch()
    except OSError as exc:
        raise C.ConfigError(path, "clock", f"a folder to write {Path(path).name}.ready.{robot_id} in "
                            f"({exc.strerror})") from None
    deadline = time.monotonic() + timeout
    while not Path(path).exists():
        if time.monotonic() > deadline:
            raise C.ConfigError(path, "clock", f"the simulator to start within {timeout:.0f} s")
        time.sleep(0.01)


def _check_args(args) -> None:
    """The options, before anything starts: numbers in range, output files in folders that exist."""
    from runtime import argcheck

    argcheck.number(args.speedup, "--speedup", 0.0, lo_open=True)
    argcheck.number(args.epoch, "--epoch")
    argcheck.number(args.duration, "--duration", 0.0, lo_open=True)
    argcheck.output_file(args.stats, "--stats")
    argcheck.output_file(args.clock_file, "--clock-file")


def _main(args) -> int:
    _check_args(args)
    cfg = C.load_robot(args.config)
    C.validate_robot(cfg)             # what start-up needs, checked before any device or socket opens
    if args.check:
        print(f"{args.config}: ok (robot {cfg.robot.id}, base {cfg.base.type}, allocation {cfg.allocation.method})")
        return 0
    daemon = Daemon(cfg)
    if args.clock_file:
        _wait_for_clock(args.clock_file, cfg.robot.id)
        clock: Clock = SharedClock(args.clock_file, args.speedup or 1.0)
    elif args.speedup is not None or args.epoch is not None:
        clock = ScaledClock(args.speedup or 1.0, args.epoch)
    else:
        clock = WallClock()
    if cfg.comms.signing_key is None:
        daemon.log.warning("MAVLink signing is off (comms.signing_key is not set): any host on the network can "
                           "command this robot")
    return run(daemon, clock, args.duration, args.stats)
