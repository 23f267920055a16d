"""The narrow views of a robot core that its ground services use (:mod:`runtime.comms.ground`): what a ground
station may read and ask of the robot, and nothing of how the core or its host is built.

Requests that change the fleet (hand tasks in, clear the mission, arm or disarm) return the messages the core
must send to its peers; the ground services hand them back to the core with the replies they produce.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class BaseFacts:
    """What the core knows of its base without talking to it: its size and speed, whether it has range sensors,
    and whether its faults latch until an operator resets them."""
    radius: float                     # m, the footprint (obstacle inflation, avoidance)
    max_speed: float = 0.5            # m/s
    ranging: bool = False             # range sensors: an empty reading means nothing in range
    latches_faults: bool = False      # faults stay, and the base stands, until reset
    # the sensor kinds the robot carries (its base's and its sensors: entries', e.g. ("laser", "sonar")), which
    # the allocation is told; None: not known to the host (the agent reads them from the config)
    kinds: tuple[str, ...] | None = None

    @classmethod
    def of(cls, base, sensors=()) -> "BaseFacts":
        """What a host reads off an opened base and its ``sensors:`` parts (a part reporting ranges makes the robot
        a ranging one; the kinds are the base's and the parts')."""
        fp = base.footprint
        lasers = any(s.reports == "ranges" for s in sensors)
        kinds = tuple(sorted(set(getattr(base, "sensor_kinds", ())) | {s.kind for s in sensors}))
        return cls(float(fp.radius), float(getattr(fp, "max_speed", 0.5)), bool(base.ranging or lasers),
                   bool(base.latches_faults), kinds)


class RobotPort:
    """A robot core as its ground services see it."""

    def __init__(self, core: Any):
        self._core = core

    # ------------------------------------------------------------------ what the robot is
    @property
    def robot_id(self) -> int:
        return self._core.id

    @property
    def datum(self):
        return self._core.cfg.datum

    @property
    def method_name(self) -> str:
        return self._core.method.name

    @property
    def task_kinds(self) -> tuple[str, ...]:
        return tuple(self._core.method.task_kinds)

    @property
    def allocation_options(self):
        return self._core.cfg.allocation

    @property
    def now(self) -> float:
        """The time of the robot's last control cycle (0 before the first)."""
        return self._core.last_step or 0.0

    def pose(self):
        return self._core.pose()

    def refuse(self, pose, x: float, y: float) -> str | None:
        """Why the robot's planner refuses a goal at (x, y), or None."""
        return self._core.planner.refuse(pose, x, y)

    # ------------------------------------------------------------------ the fleet's tasks
    def listing(self) -> list:
        return self._core.node.table.listing()

    @property
    def digest(self) -> int:
        return self._core.node.table.digest

    def hand_in(self, items, now: float) -> list:
        """An accepted upload: ``(command, frame, params, x, y)`` per item, fleet frame."""
        return self._core.node.add_items(items, now)

    def clear(self, now: float) -> list:
        return self._core.node.clear(now)

    def answer_table(self, dest: int) -> list:
        return self._core.node.answer_table(dest)

    def robot_state(self):
        return self._core.node.robot_state()

    def held(self) -> tuple[int, ...]:
        return self._core.node.held()

    def pop_notices(self) -> list:
        return self._core.node.pop_notices()

    # ------------------------------------------------------------------ arming and the base
    @property
    def armed(self) -> bool:
        return self._core.node.armed

    def set_armed(self, armed: bool, now: float) -> list:
        return self._core.node.set_armed(armed, now)

    @property
    def base(self) -> BaseFacts:
        return self._core.base

    def faults(self) -> tuple[str, ...]:
        return tuple(getattr(self._core.sensors, "faults", ()))

    def reset_faults(self, now: float) -> bool:
        """Ask the host to reset the base's latched faults; True if a reset was started (the base latches its
        faults and reports some)."""
        return self._core.request_fault_reset(now)

    # ------------------------------------------------------------------ the operator's mode, home and streams
    @property
    def mode(self) -> str:
        """"auto" (takes tasks), "hold" (paused: stands, takes none) or "rtl" (drives to its home)."""
        return self._core.mode

    def set_mode(self, mode: str, now: float) -> list:
        return self._core.set_mode(mode, now)

    @property
    def home(self) -> tuple[float, float] | None:
        """Where the robot started (its first pose, fleet frame), where RTL drives it; None before a pose."""
        return self._core.home

    def message_interval(self, msg_id: int) -> int | None:
        """A telemetry stream's interval (us; -1 off), None if the robot does not stream ``msg_id``."""
        return self._core.telemetry.interval(msg_id)

    def set_message_interval(self, msg_id: int, interval_us: float) -> bool:
        return self._core.telemetry.set_interval(msg_id, interval_us)

    def stream_message(self, msg_id: int):
        """Telemetry stream ``msg_id`` as it stands now (REQUEST_MESSAGE), or None."""
        return self._core.stream_message(msg_id)

    # ------------------------------------------------------------------ tunables
    @property
    def tunables(self):
        return self._core.executive.ctx.tunables

    def tune(self, **changes: float) -> None:
        """Change control tunables now (running executors too); a new cruise speed also goes to the estimates the
        robot bids with."""
        self._core.tune(**changes)
