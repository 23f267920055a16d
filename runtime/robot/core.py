"""The robot core (sans-IO): the fleet node (task table + allocation agent), the executive, the pose estimate,
the planner and the robot's ground-station services, advanced by one call.

:meth:`RobotCore.step` takes the time, what the robot sensed (:class:`Sensed`: odometry, fixes, the base's
sensors) and what arrived (:class:`Inbox`: peers' messages, ground-station requests, peers the link lost) and
returns an :class:`Output`: the wheel command, the frames to send in order, and whether the base is asked to reset
its faults.  It opens no socket or device, never sleeps and never reads a clock, so the same object runs in the
daemon (:mod:`runtime.daemon`, an I/O shell), in the lock-step SITL and in the in-process fleets.  Anchors: h11's
``Connection`` (the protocol state is one object, I/O outside); ArduPilot's vehicle code, the same on hardware
and in SITL.

One cycle, in order:
1. sense: odometry and fixes into the pose filter;
2. allocate: peers' messages to the fleet node, lost peers, ground-station requests, the agent's tick;
3. execute: executors for the agent's commitments vote in the arbiter -> the command (zero when disarmed);
   their progress back to the agent;
4. report: telemetry, the robot's state and its task events to the ground stations.
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence
import dataclasses
from dataclasses import dataclass, field

from runtime.comms.telemetry import MODES
from runtime.drivers.base import BaseSensors
from runtime.execution import peer_readings
from runtime.execution.executive import NONE
from runtime.fleet.node import Notice
from runtime.log import get_logger
from runtime.messages import FLEET_MESSAGES, MAX_ROBOT, OPEN
from runtime.robot.ports import BaseFacts, RobotPort
from runtime.robot.sensing import PoseEstimate
from runtime.tasks.goto import Goto
from runtime.tasks.model import Commitment, Task

HOME_TASK = 0                  # the executor's id of the drive home (RTL); fleet task ids are never 0 (origin >= 1)
PEERS, GCS, TO = "peers", "gcs", "to"          # Output.frames: ("peers", msg) | ("gcs", msg) | ("to", msg, addr)


@dataclass
class Sensed:
    """What the robot sensed since the last cycle."""
    odometry: tuple[float, float] | None = None    # (v m/s, w rad/s) when the base gave a new reading
    fixes: Sequence = ()                           # GPS fixes (``valid``, ``lat``, ``lon``, ``alt``)
    sensors: object = None                         # the base's BaseSensors: bumpers, ranges, battery, faults
    ranges: Sequence = ()                          # (bearing, distance) pairs of the robot's range sensors beside
    #                                                its base (a laser scanner's latest revolution), robot frame
    pose: tuple[float, float, float] | None = None  # a pose from outside the filter (a motion-capture system, a
                                                   # simulation's truth): the core takes it as its estimate


@dataclass
class Inbox:
    """What arrived since the last cycle."""
    peers: Sequence = ()                 # decoded peer messages, in arrival order
    ground: Sequence = ()                # (pymavlink message, source address) from ground stations
    lost: Sequence[int] = ()             # peers whose heartbeats timed out now (lost once their messages have too)
    alive: Iterable[int] = ()            # peers whose heartbeats were heard within the timeout (a peer never heard
    #                                      is lost after the start-up grace)
    ground_present: bool = False         # a ground station is listening (telemetry counts what it sends)


@dataclass
class Output:
    command: tuple[float, float] = (0.0, 0.0)      # (v, w) for the base
    frames: list = field(default_factory=list)     # what to send, in order
    reset_faults: bool = False                     # ask the base to reset its latched faults
    progress: list = field(default_factory=list)   # what the executors reported this cycle (arrived, loaded ...)

    def peer_messages(self) -> list:
        return [f[1] for f in self.frames if f[0] == PEERS]


@dataclass
class CoreStats:
    cycles: int = 0
    agent_sent: int = 0
    agent_received: int = 0
    peers_lost: list = field(default_factory=list)
    peers_joined: list = field(default_factory=list)      # robots outside comms.peers taken into the roster


class Radio:
    """Where the core's ground services and telemetry put what they send this cycle (in order), with the link's
    HEARTBEAT fields, which the host copies onto its link.  Messages are encoded with the MAVLink ``mav``
    (pymavlink's encoder for the fleet's dialect ``module``); nothing is packed or sent here."""

    def __init__(self, mav, module, counters):
        self.mav = mav
        self.module = module
        self.counters = counters          # the link's receive counters (SYS_STATUS reads them)
        self.frames: list = []
        self.present = False
        self.base_mode = 0
        self.custom_mode = 0
        self.system_status = 0

    def send_gcs(self, mavmsg) -> bool:
        self.frames.append((GCS, mavmsg))
        return self.present

    def send_to(self, mavmsg, addr) -> bool:
        self.frames.append((TO, mavmsg, addr))
        return True


class RobotCore:
    """One robot's logic.  ``base``: what the core knows of the base (:class:`BaseFacts`).  ``mavlink``:
    ``(mav, module, counters)`` to serve ground stations over MAVLink (None: no ground services, as in
    the in-process fleets, whose operator hands tasks in through :attr:`port`).  ``seed``: the robot's own random
    choices (escape turns; default its id).  ``base_config``: what the agent is told the robot is (default the
    config's ``base``; None: nothing).  ``method``: the allocation method (default the registry's entry named by
    ``cfg.allocation.method``; a host may give one that is not registered).  ``state_period``: s between the
    fleet node's state broadcasts.  ``joins``: robots outside ``comms.peers`` join the roster when their first message
arrives (default: whether the config's transport lets them, :func:`runtime.comms.transport.transport_joins`:
Zenoh yes, UDP no; a host whose bus reaches every robot, as the in-memory bus does, may say True)."""

    def __init__(self, cfg, base: BaseFacts, *, mavlink=None, seed: int | None = None, base_config=...,
                 method=None, state_period: float = 1.0, joins: bool | None = None):
        from runtime.allocation import registry
        from runtime.allocation.agent import AgentContext
        from runtime.execution.executive import ExecContext, Executive, Tunables
        from runtime.comms.liveness import PeerLiveness
        from runtime.comms.transport import transport_joins
        from runtime.fleet.node import FleetNode
        from runtime.planning.robot_planner import RobotPlanner, TravelEstimator
        from runtime.tasks import Profile

        self.cfg = cfg
        self.id = cfg.robot.id
        self.base = base
        self.log = get_logger("daemon", self.id)
        self.stats = CoreStats()
        self.sensing = PoseEstimate(cfg, self.id)
        self.ekf = self.sensing.ekf
        c = cfg.control
        radius = float(base.radius)
        self.planner = RobotPlanner.from_config(cfg, radius)
        self.estimator = TravelEstimator(self.planner, Profile(speed=c.cruise_speed, radius=radius), self.pose)
        self.method = registry.method(cfg.allocation.method) if method is None else method
        peers = tuple(p.id for p in cfg.comms.peers)
        self.agent = self.method.make(AgentContext(self.id, peers, self.estimator, cfg.allocation,
                                                   cfg.base if base_config is ... else base_config, base.kinds))
        self.node = FleetNode(self.id, self.agent, armed=cfg.robot.armed, peers=list(peers), state_period=state_period)
        self.liveness = PeerLiveness(peers, cfg.comms.heartbeat_timeout)    # lost: no heartbeat and no message
        self.joins = transport_joins(cfg.comms.transport) if joins is None else bool(joins)
        self.executive = Executive(ExecContext(self.planner, Tunables(c.cruise_speed, c.lookahead, c.max_turn_rate,
                                                                      c.goal_tolerance), self.log, radius,
                                               seed=self.id if seed is None else seed, robot_id=self.id))
        self._perceive = getattr(self.agent, "perceive", None)    # agents that read the robot's pose and ranges
        self._guidance = getattr(self.agent, "guidance", None)    # agents that tell their executors what to do
        self.port = RobotPort(self)
        self.radio = self.ground = self.telemetry = None
        if mavlink is not None:
            from runtime.comms.ground import GroundServices
            from runtime.comms.telemetry import GcsTelemetry
            self.radio = Radio(*mavlink)
            self.telemetry = GcsTelemetry(self.radio, self.id, cfg.datum, armed=cfg.robot.armed, gps=cfg.has_gps)
            self.ground = GroundServices(self.port, self.radio)
        self.period = 1.0 / c.rate
        self.mode = "auto"                       # the operator's: auto (takes tasks), hold (paused), rtl (goes home)
        self.home: tuple[float, float] | None = None    # the first pose: where RTL drives
        self._home_reached = False
        self._fixes: Sequence = ()               # the GPS fixes of this cycle (telemetry)
        self.sensors = BaseSensors()             # the base's sensors as last sensed, with the sensors' ranges
        self.laser: Sequence = ()                # the sensors: entries' own readings, as last sensed
        self._truth: tuple[float, float, float] | None = None     # Sensed.pose, when the host gives one
        self.last_step: float | None = None
        self._first_cycle: float | None = None
        self._heard: set[int] = set()            # peers heard at least once
        self._never_heard_reported = False
        self._held_back: list = []               # peer messages for the agent that came in service()
        self._frames: list = []
        self._reset = False

    def prepare(self) -> None:
        """Import now what the first cycles would import on first use (the executors of the method's task kinds,
        the planner's cost functions), so that no cycle of a running base waits on an import: a CiA 402 drive
        faults when its master is silent for 0.3 s, and a loaded machine takes that long over scipy's imports."""
        from runtime.execution import executor_class
        from runtime.planning import costs  # noqa: F401

        for kind in self.method.task_kinds:
            executor_class(kind)

    # ------------------------------------------------------------------ views
    def locate(self, pose: tuple[float, float, float]) -> None:
        """A pose from outside the filter before the first cycle (a simulation's truth): the agent's first bids
        use it.  The next :meth:`step` replaces it with what it senses."""
        self._truth = pose

    def pose(self) -> tuple[float, float, float] | None:
        return self._truth if self._truth is not None else self.sensing.pose()

    def velocity(self) -> tuple[float, float]:
        return self.sensing.velocity()

    # ------------------------------------------------------------------ one cycle
    def step(self, now: float, sensed: Sensed, inbox: Inbox) -> Output:
        self.stats.cycles += 1
        dt = 0.0 if self.last_step is None else now - self.last_step
        self.last_step = now
        self.sensors = sensors_with(sensed.sensors, sensed.ranges)
        self.laser = sensed.ranges                 # the sensors: entries' own readings (a laser's revolution)
        self._truth = sensed.pose
        self._fixes = sensed.fixes
        if sensed.pose is None:
            self.sensing.update(dt, sensed.odometry, sensed.fixes)
        if self.home is None and self.pose() is not None:
            self.home = tuple(float(v) for v in self.pose()[:2])
        if self._perceive is not None:
            self._perceive(self.pose(), self.sensors.ranges, now)
        self._peers(self._comms(now, inbox, tick=True))
        command, progress = self._execute(now)
        self._report(now, inbox)
        out = self._output(command)
        out.progress = progress
        return out

    def receive(self, msg, now: float) -> list:
        """One peer message at its own time, for hosts that deliver messages one by one (the in-memory bus);
        returns the messages to send at that time."""
        self.stats.agent_received += 1
        sender = getattr(msg, "sender", None)
        out = self._admit(sender, now)
        self.liveness.hear(sender, now)
        out += self.node.on_message(msg, now)
        self.stats.agent_sent += len(out)
        return out

    def service(self, now: float, inbox: Inbox) -> Output:
        """Messages only, no control cycle: peers' task tables and ground-station requests (a SITL operator hands
        tasks in before the first cycle this way).  Peer messages for the agent wait for the next step."""
        self._peers(self._comms(now, inbox, tick=False))
        return self._output((0.0, 0.0))

    def _output(self, command) -> Output:
        frames, self._frames = self._frames, []
        if self.radio is not None:
            frames += self.radio.frames       # ground frames were merged in order by _peers; the rest now
            self.radio.frames = []
        reset, self._reset = self._reset, False
        return Output(command, frames, reset)

    def _peers(self, msgs: list) -> None:
        """Queue ``msgs`` for the peers, after whatever the ground services said before them."""
        if self.radio is not None:
            self._frames += self.radio.frames
            self.radio.frames = []
        if msgs:
            self.stats.agent_sent += len(msgs)
            self._frames += [(PEERS, m) for m in msgs]

    def _comms(self, now: float, inbox: Inbox, tick: bool) -> list:
        pose = self.pose()
        node = self.node
        node.begin(None if pose is None else (pose[0], pose[1]))
        out = []
        held, self._held_back = self._held_back, []
        for msg in inbox.peers:
            sender = getattr(msg, "sender", None)
            out += self._admit(sender, now)
            self.liveness.hear(sender, now)
        for msg in held + list(inbox.peers):
            if not tick and _for_agent(msg):
                self._held_back.append(msg)           # service(): the agent hears it at the next step
                continue
            self.stats.agent_received += 1
            out += node.on_message(msg, now)
        if tick:
            for lost in self.liveness.due(now, inbox.lost, inbox.alive):
                self.stats.peers_lost.append(lost)
                self.log.warning("peer %d lost (no heartbeat and no message for %.1f s): re-auctioning its work",
                                 lost, self.cfg.comms.heartbeat_timeout)
                out += node.on_peer_lost(lost, now)
            for lost in self._never_heard(now, inbox.alive):
                self.stats.peers_lost.append(lost)
                self.log.warning("peer %d never heard in %.1f s (comms.startup_grace): treating it as lost",
                                 lost, self.cfg.comms.startup_grace)
                out += node.on_peer_lost(lost, now)
        if self.ground is not None:
            self.radio.present = inbox.ground_present
            out += self.ground.serve(now, inbox.ground)
        if tick:
            out += node.tick(now)
        return out

    @property
    def roster(self) -> set[int]:
        """The configured peers and the robots that joined since: the fleet node's (it takes messages from them)."""
        return set(self.node.peers)

    def _admit(self, sender, now: float) -> list:
        """A message from a robot outside the roster: over a transport that lets robots join (``joins``), it joins
        now, before its message is taken (the fleet node and the agent are told, its silence is tracked from here on
        as a configured peer's).  The link took the message, so it is signed when the fleet signs; a robot is seen
        only once it sends one, never from a liveliness token alone (the router is not trusted)."""
        if (not self.joins or not isinstance(sender, int) or isinstance(sender, bool) or sender == self.id
                or sender in self.node.peers or not 1 <= sender <= MAX_ROBOT):
            return []
        self.liveness.admit(sender)
        self.stats.peers_joined.append(sender)
        self.log.info("peer %d joined the fleet (its first message): taken into the roster", sender)
        return self.node.on_peer_joined(sender, now)

    def _never_heard(self, now: float, alive: Iterable[int]) -> list[int]:
        """Configured peers not heard once within ``comms.startup_grace`` of the first cycle, reported once:
        the link only times out peers it has heard, and a robot that never came up must not hold the
        allocation back (the epsilon auction waits for every live peer's rung).  If it turns up later, its
        first message makes it live again."""
        if self._never_heard_reported:
            return []
        if self._first_cycle is None:
            self._first_cycle = now
        self._heard.update(alive)
        if now - self._first_cycle < self.cfg.comms.startup_grace:
            return []
        self._never_heard_reported = True
        return sorted(p.id for p in self.cfg.comms.peers if p.id not in self._heard)

    def _execute(self, now: float) -> tuple[tuple[float, float], list]:
        """Executors for the agent's commitments vote in the arbiter; the command (zero when disarmed) goes to the
        base; their progress goes back to the agent."""
        ex = self.executive
        guidance = self._guidance(now) if self._guidance is not None and self.node.armed else NONE
        commitments = self.agent.commitments if self.node.armed else ()
        if self.mode == "rtl" and self.node.armed and self.home is not None:
            commitments = (Commitment(Task(HOME_TASK, "goto", Goto(*self.home, None))),)    # stays there
        ex.sync(commitments, now, guidance)
        ex.make_way = self.node.armed
        pose, sensors = self.pose(), self.sensors
        ex.peers = () if pose is None or self.base.ranging or not ex.idle else \
            peer_readings.readings(pose, self.node.positions, now, ex.ctx.radius)    # idle, no range sensors
        (v, w), progress = ex.step(pose, sensors, now, guidance)
        out = []
        for p in progress:
            if p.task == HOME_TASK:
                if p.event == "arrived" and not self._home_reached:
                    self._home_reached = True
                    self.node.notices.append(Notice("returned to launch: at home", 5))
                continue
            out += self.node.on_progress(p, now)
        self._peers(out)
        return (v, w), [p for p in progress if p.task != HOME_TASK]

    def _report(self, now: float, inbox: Inbox) -> None:
        if self.ground is None:
            return
        self.radio.present = inbox.ground_present
        commitments = self.agent.commitments
        tel = self.telemetry
        tel.armed, tel.mode, tel.home = self.node.armed, self.mode, self.home
        tel.busy = any(e.state == OPEN for e in self.node.table.listing())
        tel.tick(now, self.pose(), self.velocity(), self.sensors, commitments[0].task_id if commitments else None,
                 self._fixes)
        self.ground.report(now)

    # ------------------------------------------------------------------ requests from the ground services
    def set_mode(self, mode: str, now: float) -> list:
        """The operator's mode: "auto" takes tasks again, "hold" stops the robot and hands its tasks back to the
        fleet, "rtl" hands them back and drives home.  Returns the messages for the peers."""
        if mode not in MODES:
            raise ValueError(f"mode {mode!r}: expected one of {', '.join(MODES)}")
        if mode == self.mode:
            return []
        self.mode = mode
        self._home_reached = False
        self.log.info("mode %s", mode)
        says = {"auto": "mode AUTO: taking tasks", "hold": "mode HOLD: stopped, tasks released",
                "rtl": "mode RTL: tasks released, returning to launch"}[mode]
        return self.node.set_paused(mode != "auto", now, says)

    def stream_message(self, msg_id: int):
        name = self.telemetry.stream_name(msg_id)
        if name not in self.telemetry.streams:
            return None
        return self.telemetry.message(name, self.last_step or 0.0, self.pose(), self.velocity(), self.sensors)

    def request_fault_reset(self, now: float) -> bool:
        if not (self.base.latches_faults and getattr(self.sensors, "faults", ())):
            return False
        self._reset = True
        return True

    def tune(self, **changes: float) -> None:
        from runtime.tasks import Profile
        self.executive.tune(**changes)
        if "cruise_speed" in changes:
            self.estimator.profile = Profile(speed=float(changes["cruise_speed"]), radius=self.estimator.profile.radius)

    # ------------------------------------------------------------------ status
    def snapshot(self) -> dict:
        """The core's part of a status snapshot (the host adds its devices' and links' counters)."""
        s, p = self.stats, self.planner.stats
        return {
            "robot": self.id, "pose": self.pose(), "state": self.node.state,
            "tasks": [c.task_id for c in self.agent.commitments],
            "converged": bool(self.agent.converged), "arrived": self.executive.arrived,
            "cycles": s.cycles, "agent_sent": s.agent_sent, "agent_received": s.agent_received,
            "peers_lost": s.peers_lost, "peers_joined": s.peers_joined,
            "gps_rejected": getattr(self.ekf, "gps_rejected", 0),
            "relocalised": self.ekf.stats.relocalised,     # the pose filter gave up its position and heading
            "made_way": self.executive.made_way,           # idle cycles spent moving off for another robot
            "plan_fallbacks": p.plan_fallbacks, "plan_failures": p.plan_failures, "bid_fallbacks": p.bid_fallbacks,
            "table": len(self.node.table.entries),
            "fleet_dropped": dict(self.node.dropped),
            "agent_dropped": _drops(self.agent),
        }


def sensors_with(base_sensors, ranges: Sequence) -> BaseSensors:
    """The base's sensors (none: the defaults) with the range sensors' readings after the base's own: what the
    arbiter and the agent read.  Without such readings the base's object itself."""
    if base_sensors is None:
        base_sensors = BaseSensors()
    if not ranges:
        return base_sensors
    return dataclasses.replace(base_sensors, ranges=tuple(base_sensors.ranges) + tuple(ranges))


def _drops(agent) -> dict:
    """What the allocation agent dropped, by reason (a family without reasons: its total)."""
    d = getattr(agent, "dropped", {})
    return dict(d) if isinstance(d, dict) else {"dropped": d}


def _for_agent(msg) -> bool:
    return not isinstance(msg, FLEET_MESSAGES)
