"""Actions of paper 003 (Def. 1): modules that produce data, consume data or accomplish a task, each
able to say what it needs of the share-restricted resources (its constraint functions).

* Information is typed (:data:`INFO`): an action's ``inputs`` must be connected to another action's
  ``outputs`` of the same type, on this robot or another one.
* Constraint functions: ``processor`` (share of a core, on the robot running the action), ``rates`` (Mb/s
  of each output when it is sent to another robot: charged to the link of both robots), and ``motion``,
  which c-space constraint of :mod:`~runtime.control.cspace` the action imposes on its robot
  (``survey``: Alg. 2; ``avoid``: Alg. 4; ``sensor``: Alg. 3, only while it serves another robot's region).
* ``accomplishes``: the task kinds the action can carry out itself (the top of a coalition).
* ``cost``: the action's own share of a bid (s); motion actions add their estimated travel.

A robot's :func:`catalogue` follows from its sensors: every robot can survey, detect obstacles in range
data and avoid obstacles in a list; only a robot with a laser or a sonar ring has a reader producing range
data.  A Create has neither (it must borrow another robot's); a Pioneer 3-DX has its sonar ring
(``base.sonar``); a ``sensors:`` entry of ``type: rplidar`` is a laser (the robot's host tells the agent its sensor
kinds: ``AgentContext.sensors``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable

from runtime.control.cspace import Sensor

# information types and their wire codes (Query.info)
RANGE_DATA, OBSTACLE_LIST, WAYPOINTS = "range_data", "obstacle_list", "waypoints"
INFO = {RANGE_DATA: 1, OBSTACLE_LIST: 2, WAYPOINTS: 3}
INFO_NAMES = {v: k for k, v in INFO.items()}

SURVEY, SENSOR, AVOID = "survey", "sensor", "avoid"        # ActionSpec.motion

# the sensors a reader can read, and the data they make (Mb/s when streamed to another robot)
SENSORS = {
    # the paper's laser (181 beams, 180 deg ahead, 8 m: Stage's default), which the kinematic reproduction simulates;
    # an RPLIDAR (all round, 12 m; a sensors: entry of type rplidar, kind "laser") is claimed as that subset of it
    "laser": Sensor(fov=math.pi, range=8.0),
    "sonar": Sensor(fov=2 * math.pi, range=5.0),           # a Pioneer ring: all round, 5 m
}
LASER_RATE = 181 * 2 * 10 * 8 / 1e6                        # 181 ranges x 2 bytes x 10 Hz: 0.029 Mb/s (an A1's
#                                                            360 x 2 x 5.5 Hz is 0.032: under the same link budgets)
SONAR_RATE = 16 * 2 * 10 * 8 / 1e6                         # 16 ranges x 2 bytes x 10 Hz: 0.0026 Mb/s
OBSTACLES_RATE = 16 * 12 * 5 * 8 / 1e6                     # 16 discs x 12 bytes x 5 Hz: 0.0077 Mb/s


@dataclass(frozen=True)
class ActionSpec:
    name: str
    code: int                                      # 1..255: the action's number on the wire
    inputs: tuple[str, ...] = ()
    outputs: tuple[str, ...] = ()
    accomplishes: tuple[str, ...] = ()             # task kinds
    processor: float = 0.0                         # share of one core
    rates: tuple[tuple[str, float], ...] = ()      # (output, Mb/s when sent to another robot)
    motion: str | None = None                      # SURVEY | SENSOR | AVOID | None
    sensor: str | None = None                      # key of SENSORS, for readers
    cost: float = 0.0                              # s: the action's own share of a bid
    weight: float = 1.0                            # weight of its c-space heights in the command choice

    def rate(self, info: str) -> float:
        return dict(self.rates).get(info, 0.0)


SURVEY_ACTION = ActionSpec("survey", 1, accomplishes=("surveillance",), processor=0.02, motion=SURVEY)
AVOIDER = ActionSpec("obstacle_avoider", 2, inputs=(OBSTACLE_LIST,), accomplishes=("avoid_obstacles",),
                     processor=0.05, motion=AVOID, cost=0.1, weight=4.0)
DETECTOR = ActionSpec("obstacle_detector", 3, inputs=(RANGE_DATA,), outputs=(OBSTACLE_LIST,), processor=0.15,
                      rates=((OBSTACLE_LIST, OBSTACLES_RATE),), cost=0.3)
LASER = ActionSpec("laser_reader", 4, outputs=(RANGE_DATA,), processor=0.05, rates=((RANGE_DATA, LASER_RATE),),
                   motion=SENSOR, sensor="laser", cost=0.2, weight=0.5)
SONAR = ActionSpec("sonar_reader", 5, outputs=(RANGE_DATA,), processor=0.02, rates=((RANGE_DATA, SONAR_RATE),),
                   motion=SENSOR, sensor="sonar", cost=0.2, weight=0.5)
READERS = {"laser": LASER, "sonar": SONAR}
ALL = (SURVEY_ACTION, AVOIDER, DETECTOR, LASER, SONAR)
BY_CODE = {a.code: a for a in ALL}


@dataclass(frozen=True)
class Catalogue:
    """The actions one robot has (by name), in code order."""
    actions: tuple[ActionSpec, ...]
    sensors: tuple[str, ...] = field(default=())

    def by_name(self, name: str) -> ActionSpec | None:
        return next((a for a in self.actions if a.name == name), None)

    def by_code(self, code: int) -> ActionSpec | None:
        return next((a for a in self.actions if a.code == code), None)

    def accomplishing(self, kind: str) -> list[ActionSpec]:
        return [a for a in self.actions if kind in a.accomplishes]

    def producing(self, info: str) -> list[ActionSpec]:
        return [a for a in self.actions if info in a.outputs]

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.actions)


def catalogue(sensors: Iterable[str] = ()) -> Catalogue:
    """The actions of a robot with these sensors (keys of :data:`SENSORS`; unknown ones are ignored)."""
    have = tuple(sorted({s for s in sensors if s in SENSORS}))
    acts = [SURVEY_ACTION, AVOIDER, DETECTOR] + [READERS[s] for s in have]
    return Catalogue(tuple(sorted(acts, key=lambda a: a.code)), have)


def sensors_of(base, entries: Iterable = ()) -> tuple[str, ...]:
    """A robot's sensor kinds from its config: its base's (a Pioneer 3-DX, ``type: arcos``, has a sonar ring unless
    ``sonar: false``; a Create has none) plus the kinds of its ``sensors:`` ``entries`` (an ``rplidar``: "laser")."""
    out = set()
    if getattr(base, "type", None) == "arcos" and getattr(base, "sonar", False):
        out.add("sonar")
    if entries:
        from runtime.drivers.registry import sensor_class
        out.update(sensor_class(e.type).kind for e in entries)
    return tuple(sorted(out))
