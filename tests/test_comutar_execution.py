"""CoMutaR's executors in the executive (phase 2): a robot with no range sensor surveys a region and avoids
obstacles with another robot's sonar, the two commitments executing at once through the c-space behaviour in the
DAMN arbiter; when the sensor robot goes silent the borrower stops, and the avoidance task moves to a third
robot.  The real agents on the in-memory bus, the real executive, robots moved on exact arcs."""
from __future__ import annotations

import logging
import math
from types import SimpleNamespace

import numpy as np
import pytest

from runtime.allocation.agent import AgentContext
from runtime.allocation.bus import InMemoryBus
from runtime.control import cspace as C
from runtime.tasks.avoid_obstacles import AvoidObstacles
from runtime.allocation.comutar.messages import CmStream, pack_disc, unpack_disc
from runtime.allocation.comutar.options import ComutarOptions
from runtime.allocation.comutar.protocol import ComutarAgent, echo_discs
from runtime.tasks.surveillance import Surveillance
from runtime.execution.executive import ExecContext, Executive, Tunables
from runtime.tasks import Profile, Task

DT = 0.05
RADIUS = {1: 0.17, 2: 0.25, 3: 0.25}
OBSTACLES = np.array([[-1.0, -1.6, 0.15], [1.6, -1.0, 0.15], [1.0, 1.6, 0.15], [-1.6, 1.0, 0.15]])
SURVEY = Task(1 << 16 | 1, "surveillance", Surveillance(0.0, 0.0, 4.0, 4.0, 2.0, robots=1))
AVOID = Task(1 << 16 | 2, "avoid_obstacles", AvoidObstacles(1))


class Est:
    def __init__(self, radius):
        self.profile = Profile(0.25, radius)

    def estimates(self, tasks):
        return []


class World:
    """Three robots: 1 has no range sensor, 2 and 3 a sonar ring (everything within 5 m: the obstacles and the
    other robots, as discs).  The discs are whole obstacles, not echoes off their near side: no shadows."""

    def __init__(self, **options):
        self.opts = ComutarOptions(**{"region_period": 0.2, "shadow_depth": 0.0, **options})
        sensors = {1: (), 2: ("sonar",), 3: ("sonar",)}
        self.agents = {r: ComutarAgent(AgentContext(r, tuple(i for i in sensors if i != r), Est(RADIUS[r]), self.opts),
                                       sensors[r]) for r in sensors}
        self.bus = InMemoryBus(dict(self.agents), delay=0.01, jitter=0.002, seed=3)
        self.poses = {1: np.array([-3.0, -2.5, 0.0]), 2: np.array([-3.5, 0.0, 0.0]), 3: np.array([3.5, 0.5, 3.1])}
        tun = Tunables(cruise_speed=0.25, lookahead=0.4, max_turn_rate=2.0, goal_tolerance=0.1)
        self.ex = {r: Executive(ExecContext(None, tun, logging.getLogger(f"test.r{r}"), RADIUS[r], seed=r))
                   for r in self.agents}
        self.now = 0.0
        self.dead: set[int] = set()
        self.commands: list[tuple[float, float, float]] = []      # robot 1: (t, v, w)
        self.clearance = math.inf                                # robot 1's least, to any obstacle
        self.visited: set[int] = set()
        for a in self.agents.values():
            a.add_tasks([SURVEY, AVOID], 0.0)

    def seen(self, r):
        if r == 1:
            return np.zeros((0, 3))
        others = [(p[0], p[1], RADIUS[i]) for i, p in self.poses.items() if i != r and i not in self.dead]
        discs = np.vstack([OBSTACLES, others])
        d = np.hypot(discs[:, 0] - self.poses[r][0], discs[:, 1] - self.poses[r][1])
        return discs[d <= 5.0]

    def step(self):
        live = [r for r in self.agents if r not in self.dead]
        for r in live:
            self.agents[r].sense(self.poses[r], self.seen(r), self.now)
        self.bus.run(self.now + DT, tick=DT)
        self.now = self.bus.now = self.now + DT
        sensors = SimpleNamespace(bump_left=False, bump_right=False, ranges=())
        for r in live:
            a, ex = self.agents[r], self.ex[r]
            guidance = a.guidance(self.now)                 # what the agent tells its executors, as data
            ex.sync(a.commitments, self.now, guidance)
            (v, w), progress = ex.step(tuple(self.poses[r]), sensors, self.now, guidance)
            for p in progress:
                self.visited.add(p.data["waypoint"]) if p.event == "visited" else None
                self.bus.send(a.on_progress(p, self.now), self.now)
            self.poses[r] = C.advance(self.poses[r], v, w, DT)[0]
            if r == 1:
                self.commands.append((self.now, v, w))
        gap = np.hypot(OBSTACLES[:, 0] - self.poses[1][0], OBSTACLES[:, 1] - self.poses[1][1]) - OBSTACLES[:, 2]
        self.clearance = min(self.clearance, float(gap.min()) - RADIUS[1])

    def run(self, until, stop=None):
        while self.now < until - 1e-9:
            self.step()
            if stop is not None and stop():
                return True
        return False

    def provider(self):
        """The robot whose sensor robot 1's avoider reads."""
        ins, _ = self.agents[1].bidder.links(AVOID.id) if AVOID.id in self.agents[1].bidder.holdings else ({}, {})
        src = ins.get("obstacle_list")
        return ins.get("range_data", src) if src == 1 else src

    def kill(self, r):
        self.dead.add(r)
        self.bus.down.add(r)


@pytest.fixture(scope="module")
def borrowed():
    """One run: robot 1 surveys with robot 2's sonar until 30 s, robot 2 dies, robot 3 takes over."""
    w = World()
    w.run(30.0)
    before = dict(visited=len(w.visited), provider=w.provider(), clearance=w.clearance,
                  holds=sorted(c.task.kind for c in w.agents[1].commitments),
                  conflicts=w.ex[1].cspace.conflicts if w.ex[1].cspace else 0)
    killed = w.now
    w.kill(2)
    w.run(killed + 3.0)                            # the daemons' heartbeat timeout: then the loss is known
    stopped = next((t for t, v, om in w.commands if t > killed and v == 0 and om == 0), None)
    stale = w.agents[1].feed_timeout("range_data")
    moved_while_blind = max((abs(v) for t, v, om in w.commands if t > killed + stale + 2 * DT), default=0)
    for r in (1, 3):
        w.bus.send(w.agents[r].on_peer_lost(2, w.now), w.now)
    lost_at = w.now
    w.run(lost_at + 30.0, stop=lambda: w.provider() == 3)
    took_over = w.now - lost_at
    w.run(w.now + 120.0, stop=lambda: len(w.visited) == len(SURVEY.spec.waypoints()))
    return SimpleNamespace(w=w, before=before, killed=killed, stopped=stopped, moved_while_blind=moved_while_blind,
                           took_over=took_over)


def test_the_sensorless_robot_holds_survey_and_avoidance_at_once_with_the_other_robots_sonar(borrowed):
    b = borrowed.before
    assert b["holds"] == ["avoid_obstacles", "surveillance"]
    assert b["provider"] == 2
    assert b["visited"] >= 3, b
    assert b["clearance"] > 0.0, b


def test_when_the_sensor_robot_goes_silent_the_borrower_stops_once_its_data_is_stale(borrowed):
    r = borrowed
    assert r.stopped is not None
    # overdue 2.5 stream periods (0.25 s for range data at 10 Hz) after the last one, stopped in that control cycle
    stale = r.w.agents[1].feed_timeout("range_data")
    assert stale == pytest.approx(0.25)
    assert r.stopped - r.killed <= stale + 0.1 + DT, r.stopped - r.killed
    assert r.moved_while_blind == 0.0


def test_the_avoidance_task_goes_to_the_third_robot_and_the_survey_is_finished_without_touching(borrowed):
    w = borrowed.w
    assert w.provider() == 3
    assert borrowed.took_over < 10.0
    assert len(w.visited) == len(SURVEY.spec.waypoints())
    assert w.clearance > 0.0
    print(f"killed at {borrowed.killed:.1f} s, stopped {borrowed.stopped - borrowed.killed:.2f} s later, robot 3 "
          f"provider {borrowed.took_over:.1f} s after the loss was known; least clearance {w.clearance:.3f} m")


def test_a_packed_disc_comes_back_within_its_resolution():
    for x, y, r in [(0.0, 0.0, 0.05), (-12.34, 7.01, 0.3), (40.0, -40.0, 2.55)]:
        v = pack_disc(x, y, r, 1.0, -1.0)
        assert v and v <= 0xFFFFFFFF
        ux, uy, ur = unpack_disc(v, 1.0, -1.0)
        assert abs(ux - x) <= 0.011 and abs(uy - y) <= 0.011 and abs(ur - r) <= 0.006
    assert pack_disc(100.0, 0.0, 0.1, 0.0, 0.0) is None
    assert CmStream(2, 1, 1 << 16 | 2, 2, 1.0, 0.0, 0.0, (0,)).invalid()


def test_echoes_become_discs_in_the_fleet_frame():
    d = echo_discs((1.0, 2.0, math.pi / 2), [(0.0, 2.0), (math.pi / 2, 1.0), (0.3, math.inf)])
    assert d.shape == (2, 3)
    assert np.allclose(d[0, :2], [1.0, 4.0]) and np.allclose(d[1, :2], [0.0, 2.0])
    assert 0.05 <= d[0, 2] <= 0.3


def test_a_sensor_covers_a_disc_only_whole_within_its_range_and_angle():
    sonar, laser = C.Sensor(fov=2 * math.pi, range=5.0), C.Sensor(fov=math.pi, range=8.0)
    here = (0.0, 0.0, 0.0)
    assert sonar.covers(here, (-3.9, 0.0), 1.0) and not sonar.covers(here, (-4.1, 0.0), 1.0)
    assert laser.covers(here, (3.0, 2.0), 1.0)
    assert not laser.covers(here, (-3.0, 0.0), 1.0)                  # behind a 180 deg laser
    assert not laser.covers(here, (0.2, 3.0), 1.0)                   # its centre in view, its side not
    assert not laser.covers(here, (0.3, 0.0), 1.0)                   # the laser inside the disc


def test_a_disc_heard_by_another_robot_is_followed_by_its_shadow():
    from runtime.allocation.comutar.protocol import shadowed

    d = shadowed(np.array([[3.0, 4.0, 0.1], [0.0, 0.0, 0.25]]), (0.0, 0.0), 0.3)
    assert d.shape == (6, 3)
    assert np.allclose(d[:2], [[3.0, 4.0, 0.1], [0.0, 0.0, 0.25]])
    far = d[2:][d[2:, 2] == 0.1]
    assert np.allclose(far[:, :2], [[3.09, 4.12], [3.18, 4.24]])      # along the beam, away from the sensor
    assert np.allclose(d[2:][d[2:, 2] == 0.25][:, :2], 0.0)            # no beam, no shadow elsewhere
    assert np.array_equal(shadowed(d, (1.0, 1.0), 0.0), d)


def _borrowing_world():
    """A world run until robot 1's avoidance reads robot 2's sonar and robot 2 knows robot 1's region."""
    w = World(shadow_depth=ComutarOptions().shadow_depth)
    assert w.run(20.0, stop=lambda: w.provider() == 2 and AVOID.id in w.agents[2].regions)
    return w


def test_the_borrower_puts_the_shadow_behind_each_streamed_disc():
    w = _borrowing_world()
    a1 = w.agents[1]
    info = next(i for i, src in a1.bidder.links(AVOID.id)[0].items() if src == 2)
    x, y, _ = a1.pose
    ox, oy = x + 2.0, y                                           # the provider 2 m east, a disc 1 m east of robot 1
    disc = pack_disc(x + 1.0, y, 0.1, ox, oy)
    a1.on_message(CmStream(2, 1, AVOID.id, {"range_data": 1, "obstacle_list": 2}[info], w.now, ox, oy, (disc,)), w.now)
    seen = a1.obstacle_input(AVOID.id, w.now)
    mine = seen[-3:]                                              # the newest frame comes last
    assert np.allclose(mine[:, 0] - x, [1.0, 0.85, 0.7], atol=0.011)     # heard from the east: the shadow is west
    assert np.allclose(mine[:, 1], y, atol=0.011)
    assert np.allclose(mine[:, 2], 0.1, atol=0.006)


def test_a_reader_streams_only_while_its_sensor_takes_in_the_consumers_whole_region():
    w = _borrowing_world()
    a2 = w.agents[2]
    x, y, _ = a2.pose
    for gap, streams in ((3.9, True), (4.1, False)):             # a 1 m region, a 5 m sonar ring
        a2.regions[AVOID.id] = (x + gap, y, 1.0)
        a2._stream_at.clear()
        sent = [m for m in a2._streams(w.now) if isinstance(m, CmStream) and m.task == AVOID.id]
        assert bool(sent) == streams, gap


def test_the_borrower_keeps_a_streamed_disc_for_the_feed_memory():
    w = _borrowing_world()
    a1 = w.agents[1]
    info = next(i for i, src in a1.bidder.links(AVOID.id)[0].items() if src == 2)
    code = {"range_data": 1, "obstacle_list": 2}[info]
    x, y, _ = a1.pose
    t0, memory = w.now, a1.options.feed_memory
    a1.on_message(CmStream(2, 1, AVOID.id, code, t0, x + 2.0, y, (pack_disc(x + 1.0, y + 1.0, 0.1, x + 2.0, y),)), t0)

    def holds(t):
        a1.on_message(CmStream(2, 1, AVOID.id, code, t, x + 2.0, y, ()), t)          # echo frames that miss it
        seen = a1.obstacle_input(AVOID.id, t)
        return bool(np.any(np.hypot(seen[:, 0] - x - 1.0, seen[:, 1] - y - 1.0) < 0.02))

    assert holds(t0 + 0.1) and holds(t0 + memory - 0.1)
    assert not holds(t0 + memory + 0.1)


def test_a_reader_left_behind_and_stuck_takes_a_detour_toward_the_region():
    from runtime.allocation.comutar import actions as A
    from runtime.execution import detour as D
    from runtime.execution.avoidance import AvoidanceExecutor
    from runtime.tasks import Commitment
    from runtime.tasks.avoid_obstacles import Guidance

    def guide(where):                                        # what the agent writes: a sonar reader's region
        return Guidance(C.Window(), None, None, (1, *where, 1.0), A.SONAR.weight, A.SENSORS["sonar"],
                        np.array([[1.0, 0.2, 0.3]]))         # an obstacle between the two, a little to the left

    ctx = SimpleNamespace(log=logging.getLogger("test.reader"), radius=0.25)
    ex = AvoidanceExecutor(Commitment(AVOID, params=(("actions", (A.SONAR.name,)),)), ctx)
    ex.guide = guide((3.5, 0.0))                             # the consumer: past 0.8 x 5 m with its 1 m region
    here = (0.0, 0.0, 0.0)
    names = []
    for i in range(int(D.STUCK_TIME / DT) + 3):                # held where it is
        ex.update(here, i * DT)
        names.append(ex.constraints()[0].name)
    assert set(names[:int(D.STUCK_TIME / DT)]) == {"sensor"} and names[-1] == "survey"
    assert ex.detour.count == 1
    ex.guide = guide((2.5, 0.0))                             # in view again: Alg. 3 again, no detour
    ex.update(here, len(names) * DT)
    assert ex.constraints()[0].name == "sensor"
