"""The robot daemon: driver -> localization -> control, allocation agent <-> comms.

One :class:`Daemon` per robot.  It is a polled object: :meth:`Daemon.step` does one control cycle at
time ``now`` and never blocks, so the same object runs in its own process against real devices
(:func:`run`, wall or scaled clock) or lock-stepped inside the SITL process (tests, experiments).

Cycle: read the base (odometry, bumpers) and GPS -> EKF -> drain MAVLink (agent messages, peer
liveness) -> agent tick -> send agent messages -> follow the path to the held task (pure pursuit under
the arbiter) -> command the base -> ground-station telemetry.
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
    plan_fallbacks: int = 0        # RRT found no path, the A* path was taken
    bid_fallbacks: int = 0         # bid costs the first RRT tree missed (priced by a second tree or A*)
    plan_failures: int = 0         # no path at all: headed straight for the goal


def make_agent(cfg: C.RobotConfig, cost):
    """The allocation agent named by ``cfg.allocation.method``."""
    peers = [p.id for p in cfg.comms.peers]
    method = cfg.allocation.method
    if method == "bs":
        from runtime.allocation.formation.bs import BSAgent as Agent
    elif method == "rtma":
        from runtime.allocation.formation.rtma import RTMAAgent as Agent
    else:
        from runtime.allocation.formation.eps_auction import EpsAuctionAgent as Agent
    return Agent(cfg.robot.id, peers, cost, bid_timeout=cfg.allocation.bid_timeout)


class Daemon:
    def __init__(self, cfg: C.RobotConfig, *, base=None, gps=None, link=None):
        from runtime.control.arbiter import Arbiter, ArcSet, AvoidObstacles, FollowPath, Stop
        from runtime.control.pure_pursuit import PurePursuit
        from runtime.localization.ekf import PoseEKF
        from runtime.localization.enu import geodetic_to_enu

        self.cfg = cfg
        self.id = cfg.robot.id
        self.log = get_logger("daemon", self.id)
        self.stats = DaemonStats()
        self._geodetic_to_enu = geodetic_to_enu
        if base is None:
            from runtime.drivers.create_oi import CreateOI
            b = cfg.base
            base = CreateOI(b.port, model=b.model, baudrate=b.baudrate, mode=b.mode,
                            watchdog=b.watchdog, max_speed=b.max_speed, robot_id=self.id)
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
                               heartbeat_timeout=cfg.comms.heartbeat_timeout)
        self.link = link
        from runtime.comms.telemetry import GcsTelemetry
        self.telemetry = GcsTelemetry(link, self.id, cfg.datum)
        self.ekf = PoseEKF(cfg.localization)
        if cfg.localization.initial_pose is not None:
            self.ekf.initialise(*cfg.localization.initial_pose)
        self.tasks = {i: tuple(xy) for i, xy in enumerate(cfg.allocation.formation)}
        self.agent = make_agent(cfg, self._cost)
        c = cfg.control
        self.pursuit = PurePursuit(lookahead=c.lookahead, cruise_speed=c.cruise_speed,
                                   max_turn_rate=c.max_turn_rate, goal_tolerance=c.goal_tolerance)
        self.follow = FollowPath(follower=self.pursuit)
        self.avoid = AvoidObstacles()
        self.arbiter = Arbiter(ArcSet.uniform(max_speed=c.cruise_speed, max_turn_rate=c.max_turn_rate),
                               [self.follow, self.avoid, Stop(self.follow)])
        self.map = self._load_map(cfg)
        self._cost_row: dict[int, float] = {}
        self._cost_at: tuple[float, float] | None = None
        self.period = 1.0 / c.rate
        self._last_step: float | None = None
        self._last_odom_t: float | None = None
        self._first_cycle: float | None = None
        self._heard: set[int] = set()            # peers heard at least once
        self._never_heard_reported = False
        self._started = False
        self._target: int | None = None
        self._path: list[tuple[float, float]] = []
        self._backing_up = False

    # ------------------------------------------------------------------ costs and pose
    def pose(self) -> tuple[float, float, float] | None:
        return self.ekf.pose() if self.ekf.initialised else None

    @staticmethod
    def _load_map(cfg: C.RobotConfig):
        if cfg.planning.map is None:
            return None
        path = Path(cfg.planning.map)
        if not path.is_absolute() and cfg.source:
            path = Path(cfg.source).parent / path
        return C.load_world(path)

    @property
    def planner(self) -> str:
        return self.cfg.planning.planner if self.map is not None else "euclid"

    def _cost(self, task: int) -> float:
        """Bid cost: planned path length from the current pose estimate to ``task`` (inf if unreachable).
        One search fills the row for every known task; it is reused until the robot moves 0.25 m."""
        from runtime.planning.costs import bid_costs

        pose = self.pose()
        if pose is None or task not in self.tasks:
            return math.inf
        if (self._cost_at is None or task not in self._cost_row
                or math.hypot(pose[0] - self._cost_at[0], pose[1] - self._cost_at[1]) > 0.25):
            ids = sorted(self.tasks)
            row, missed = bid_costs(self.map, pose[:2], [self.tasks[i] for i in ids], planner=self.planner,
                                    seed=self.id, inflate=self.cfg.planning.inflate,
                                    rrt_iterations=self.cfg.planning.rrt_iterations)
            self.stats.bid_fallbacks += missed
            self._cost_row = {i: float(c) for i, c in zip(ids, row)}
            self._cost_at = (pose[0], pose[1])
        return self._cost_row[task]

    def _plan(self, pose, goal) -> list[tuple[float, float]]:
        """The path to drive to ``goal``: the configured planner's, A*'s when RRT misses (see
        :func:`runtime.planning.costs.plan_route`), a straight line when the map has none at all."""
        from runtime.planning.costs import plan_route

        if self.map is None:
            return [(pose[0], pose[1]), goal]
        p = self.cfg.planning
        route, used = plan_route(self.map, pose[:2], goal, planner=self.planner, seed=self.id, inflate=p.inflate,
                                 rrt_iterations=p.rrt_iterations)
        if route is None:
            self.stats.plan_failures += 1
            self.log.warning("no path to (%.2f, %.2f) on the map: heading straight for it", *goal)
            return [(pose[0], pose[1]), goal]
        if used != self.planner:
            self.stats.plan_fallbacks += 1
            self.log.warning("%s found no path to (%.2f, %.2f) in two trees: following the %s path", self.planner,
                             *goal, used)
        return route

    # ------------------------------------------------------------------ lifecycle
    def open(self, now: float) -> None:
        self.base.open(now)
        if self.gps is not None:
            self.gps.open(now) if hasattr(self.gps, "open") else None
        self.log.info("open: base %s, gps %s, listening %s", self.cfg.base.port,
                      self.cfg.gps.port if self.gps else "off", self.cfg.comms.listen)

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
        self._control(now)
        self.telemetry.tick(now, self.pose(), self._velocity(), self.base.sensors,
                            self.agent.assignment, self.agent.converged)

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

    def _allocate(self, now: float) -> None:
        out = []
        if not self._started and self.ekf.initialised:
            self._started = True
            if self.cfg.allocation.initiator and self.tasks:
                out += self.agent.start(self.tasks, now)
        for msg in self.link.poll(now):
            self.stats.agent_received += 1
            if hasattr(msg, "x") and hasattr(msg, "task"):
                self.tasks.setdefault(msg.task, (msg.x, msg.y))
            if self._started:
                out += self.agent.on_message(msg, now)
        for lost in self.link.peers_lost(now):
            self.stats.peers_lost.append(lost)
            self.log.warning("peer %d lost (no heartbeat for %.1f s): re-auctioning its work",
                             lost, self.cfg.comms.heartbeat_timeout)
            out += self.agent.on_peer_lost(lost, now)
        for lost in self._never_heard(now):
            self.stats.peers_lost.append(lost)
            self.log.warning("peer %d never heard in %.1f s (comms.startup_grace): treating it as lost",
                             lost, self.cfg.comms.startup_grace)
            out += self.agent.on_peer_lost(lost, now)
        if self._started:
            out += self.agent.on_tick(now)
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

    def _control(self, now: float) -> None:
        """Path to the held task, followed by pure pursuit under the DAMN-style arbiter (bumpers)."""
        pose = self.pose()
        task = self.agent.assignment
        if pose is None or task is None or task not in self.tasks:
            if self._target is not None:
                self.follow.set_path(None)
                self._target = None
            self.base.set_velocity(0.0, 0.0, now)
            return
        goal = self.tasks[task]
        tol = self.cfg.control.goal_tolerance
        if task != self._target:
            self._target = task
            self.follow.set_path(self._plan(pose, goal))
            self.log.info("driving to task %d at (%.2f, %.2f)", task, *goal)
        elif self.follow.done and math.hypot(goal[0] - pose[0], goal[1] - pose[1]) > 3 * tol:
            self.follow.set_path(self._plan(pose, goal))      # pushed off station: go back
        s = self.base.sensors
        self.avoid.on_bumpers(s.bump_left, s.bump_right, now)
        backing = self.avoid.backing_up(now)
        if self._backing_up and not backing:
            self.follow.set_path(self._plan(pose, goal))      # re-plan from where the bump left us
        self._backing_up = backing
        self.follow.update(pose, now)
        d = self.arbiter.decide(now)
        cmd = self.follow.command
        if cmd is not None and not backing and d.arc == self.arbiter.arcs.nearest(*cmd):
            v, w = cmd           # the path follower won: pass its exact command, not the arc's grid value
        else:
            v, w = d.v, d.w
        self.base.set_velocity(v, w, now)

    def snapshot(self) -> dict:
        pose = self.pose()
        s = self.stats
        return {
            "robot": self.id, "pose": pose, "task": self.agent.assignment,
            "converged": bool(self.agent.converged), "arrived": bool(self.follow.done and self._target is not None),
            "cycles": s.cycles, "missed_deadlines": s.missed_deadlines,
            "worst_lateness": s.worst_lateness, "agent_sent": s.agent_sent,
            "agent_received": s.agent_received, "peers_lost": s.peers_lost,
            "cpu_seconds": s.cpu_seconds, "wall_seconds": s.wall_seconds,
            "base": vars(self.base.stats) if hasattr(self.base, "stats") else {},
            "link": self.link.counters.as_dict() if hasattr(self.link, "counters") else {},
            "gps_rejected": getattr(self.ekf, "gps_rejected", 0),
            "plan_fallbacks": s.plan_fallbacks, "plan_failures": s.plan_failures, "bid_fallbacks": s.bid_fallbacks,
            "idle_offers": getattr(self.agent, "idle_offers", 0),
        }


# ---------------------------------------------------------------------- process main loop

class _Stop(Exception):
    """SIGTERM or SIGINT arrived: leave the loop wherever it is, then stop the motors."""


def run(daemon: Daemon, clock: Clock, duration: float | None = None, stats_path: str | None = None) -> None:
    """Run ``daemon`` at its control rate until ``duration`` (clock seconds) or SIGTERM/SIGINT."""
    def _stop(signum, frame):
        raise _Stop(signal.Signals(signum).name)

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    t0 = clock.now()
    wall0, cpu0 = time.monotonic(), time.process_time()
    next_t = t0
    last_dump = t0
    try:
        daemon.open(t0)
        while duration is None or clock.now() - t0 < duration:
            now = clock.now()
            late = now - next_t
            if late > daemon.period:       # the cycle that was due is a whole period late
                daemon.stats.missed_deadlines += 1
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


def _dump(path: str, data: dict) -> None:
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w") as fh:
        json.dump(data, fh, default=str)
    os.replace(tmp, path)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("daemon", help="run one robot's daemon from its robot config")
    p.add_argument("config", help="robot config YAML")
    p.add_argument("--check", action="store_true", help="validate the config and exit")
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
    Path(f"{path}.ready.{robot_id}").touch()
    deadline = time.monotonic() + timeout
    while not Path(path).exists():
        if time.monotonic() > deadline:
            raise C.ConfigError(path, "clock", f"the simulator to start within {timeout:.0f} s")
        time.sleep(0.01)


def _main(args) -> int:
    cfg = C.load_robot(args.config)
    if args.check:
        print(f"{args.config}: ok (robot {cfg.robot.id}, {cfg.base.model} on {cfg.base.port})")
        return 0
    daemon = Daemon(cfg)
    if args.clock_file:
        _wait_for_clock(args.clock_file, cfg.robot.id)
        clock: Clock = SharedClock(args.clock_file, args.speedup or 1.0)
    elif args.speedup is not None or args.epoch is not None:
        clock = ScaledClock(args.speedup or 1.0, args.epoch)
    else:
        clock = WallClock()
    run(daemon, clock, args.duration, args.stats)
    return 0
