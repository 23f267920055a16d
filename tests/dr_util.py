"""Shared set-ups of the dr tests (runtime/allocation/dr): fleets on the in-memory bus with kinematic transport
trips (runtime/allocation/dr/sim.py) and single agents fed by hand."""
from __future__ import annotations

import copy

from runtime.allocation.agent import AgentContext
from runtime.allocation.dr.family import DrAgent
from runtime.allocation.dr.options import DrOptions
from runtime.allocation.dr.sim import TransportFleet
from runtime.fleet.simulate import StraightLineEstimator
from runtime.tasks import Profile, Task
from runtime.tasks.transport import Transport

_BUSY = None


def busy_fleet() -> TransportFleet:
    """Five robots working on two objects (groups formed, loads on the way), built once; callers may poke it."""
    global _BUSY
    if _BUSY is None:
        f = TransportFleet({1: (-2, -1), 2: (-2, 0), 3: (-2, 1), 4: (2, -1), 5: (2, 0)}, tick=0.1,
                           options=DrOptions(strategy="NM_NI"))
        f.run(0.5)
        f.put(1, [(1.5, 1.5, 30, 60, 100), (-1.5, 1.0, 30, 60, 100)])
        f.run(25.0)
        roles = [r.agent.role(t) for r in f.robots.values() for t in r.agent.world.tasks]
        assert roles.count("leader") == 2 and "member" in roles
        _BUSY = f
    return copy.deepcopy(_BUSY)


def agent(robot_id: int = 1, peers=(1, 2, 3, 4, 5), pos=(0.0, 0.0), speed: float = 0.25, **options) -> DrAgent:
    """A lone agent at ``pos`` whose peers are ``peers``; ``options`` are DrOptions fields."""
    where = {"pos": pos}
    est = StraightLineEstimator(Profile(speed, 0.2), lambda: where["pos"])
    a = DrAgent(AgentContext(robot_id, tuple(peers), est, DrOptions(**options)))
    a.where = where                    # tests move the robot by where["pos"] = ...
    return a


def transport(task_id: int, x: float, y: float, weight: float = 10.0, deadline: float = 100.0,
              u_max: float = 100.0) -> Task:
    return Task(task_id, "transport", Transport(x, y, weight, deadline, u_max))
