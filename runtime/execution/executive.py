"""The executive: starts and cancels executors to match the allocation agent's commitments, lets them and
the robot-wide behaviours vote in the DAMN arbiter, and returns the command and the progress to report.

Robot-wide behaviours: obstacle avoidance (bumpers, range readings) and standing still when no executor
is driving.  The arbiter's winning arc is replaced by the leading executor's exact command when that
command's arc won (the path follower won: no grid rounding).
"""
from __future__ import annotations

from dataclasses import dataclass, field

from runtime.control.arbiter import Arbiter, ArcSet, AvoidObstacles, Stop
from runtime.control.pure_pursuit import PurePursuit
from runtime.execution import executor_class
from runtime.tasks import Commitment, Progress


@dataclass
class Tunables:
    """What a ground station may change while the robot runs (parameters)."""
    cruise_speed: float
    lookahead: float
    max_turn_rate: float
    goal_tolerance: float


@dataclass
class ExecContext:
    planner: object                   # runtime.planning.robot_planner.RobotPlanner
    tunables: Tunables
    log: object
    radius: float                     # m, the base's footprint (obstacle avoidance)

    @property
    def goal_tolerance(self) -> float:
        return self.tunables.goal_tolerance

    def pursuit(self) -> PurePursuit:
        t = self.tunables
        return PurePursuit(lookahead=t.lookahead, cruise_speed=t.cruise_speed, max_turn_rate=t.max_turn_rate,
                           goal_tolerance=t.goal_tolerance)


@dataclass
class Executive:
    ctx: ExecContext
    executors: dict[int, object] = field(default_factory=dict)      # task id -> executor
    arbiter: Arbiter | None = None

    def __post_init__(self) -> None:
        self.avoid = AvoidObstacles(radius=self.ctx.radius)
        self._backing = False
        self._rebuild_arbiter()

    def _arcs(self) -> ArcSet:
        t = self.ctx.tunables
        return ArcSet.uniform(max_speed=t.cruise_speed, max_turn_rate=t.max_turn_rate)

    def _rebuild_arbiter(self) -> None:
        lead = self._lead()
        follows = [b for e in self.executors.values() for b in e.behaviours]
        stop = [Stop(lead.follow)] if lead is not None else []
        if self.arbiter is None:
            self.arbiter = Arbiter(self._arcs(), follows + [self.avoid] + stop)
        else:
            self.arbiter.behaviours = follows + [self.avoid] + stop

    def _lead(self):
        return next(iter(self.executors.values()), None)

    def tune(self, **changes) -> None:
        """Apply changed tunables now: running executors' followers and the arbiter's arcs too."""
        for k, v in changes.items():
            setattr(self.ctx.tunables, k, v)
        for e in self.executors.values():
            p = e.follow.follower
            t = self.ctx.tunables
            p.lookahead, p.cruise_speed, p.max_turn_rate, p.goal_tolerance = (t.lookahead, t.cruise_speed,
                                                                              t.max_turn_rate, t.goal_tolerance)
            p.slow_radius, p.min_speed = 2.0 * t.lookahead, 0.15 * t.cruise_speed
        self.arbiter.arcs = self._arcs()

    # ------------------------------------------------------------------ commitments
    def sync(self, commitments: tuple[Commitment, ...], now: float) -> None:
        """Start executors for new commitments, cancel those whose commitment ended.  A commitment that changed
        but keeps its task goes to its executor's ``recommit`` where it has one (a transport keeps its load when
        its coalition changes), and restarts the executor where it has none."""
        want = {c.task_id: c for c in commitments}
        changed = False
        for tid in list(self.executors):
            ex = self.executors[tid]
            if tid in want and want[tid] != ex.commitment and hasattr(ex, "recommit"):
                ex.recommit(want[tid], now)          # same task, new partners or parameters: carry on
            elif tid not in want or want[tid] != ex.commitment:
                self.executors.pop(tid).cancel(now)
                changed = True
        for tid, c in want.items():
            if tid not in self.executors:
                self.executors[tid] = executor_class(c.task.kind)(c, self.ctx)
                changed = True
        if changed:
            self._rebuild_arbiter()

    @property
    def idle(self) -> bool:
        return not self.executors

    # ------------------------------------------------------------------ one control cycle
    def step(self, pose, sensors, now: float) -> tuple[tuple[float, float], list[Progress]]:
        """The command for this cycle and the progress to report.  ``pose`` None or no executor: stand still."""
        if pose is None or not self.executors:
            return (0.0, 0.0), []
        for e in self.executors.values():
            e.begin(pose, now)
        self.avoid.on_bumpers(sensors.bump_left, sensors.bump_right, now)
        ranges = getattr(sensors, "ranges", None)
        if ranges:
            self.avoid.on_ranges(ranges, now)
        backing = self.avoid.backing_up(now)
        if self._backing and not backing:
            for e in self.executors.values():
                e.bump_ended(pose, now)
        self._backing = backing
        progress = []
        for e in self.executors.values():
            progress += e.update(pose, now)
        d = self.arbiter.decide(now)
        lead = self._lead()
        cmd = lead.follow.command
        if cmd is not None and not backing and d.arc == self.arbiter.arcs.nearest(*cmd):
            return cmd, progress          # the path follower won: pass its exact command, not the arc's grid value
        return (d.v, d.w), progress

    @property
    def arrived(self) -> bool:
        lead = self._lead()
        return lead is not None and lead.follow.done
