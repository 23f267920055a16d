"""Paper 003 Section 2.1.3 and Algs. 2-4: the next-frame window, each constraint function, the empty
intersection, and the arbiter ballot a choice becomes."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

from runtime.control import cspace as C
from runtime.control.arbiter import ArcSet

WIN = C.Window()          # 0.25 m/s, 2 rad/s, 21 x 21 cells over +-0.05 m, T_f = 0.2 s


def test_every_candidate_is_a_differential_drive_arc_landing_in_its_cell():
    assert WIN.period == pytest.approx(0.2)
    end = C.advance(np.zeros((WIN.size, 3)), WIN.v, WIN.w, WIN.period)
    assert np.allclose(end[:, 0], WIN.dx, atol=1e-12) and np.allclose(end[:, 1], WIN.dy, atol=1e-12)
    assert np.allclose(end[:, 2], C.wrap(WIN.dth))
    cell = WIN.cell_size
    centres = WIN.cell_xy[WIN.cell]
    assert np.all(np.abs(end[:, :2] - centres) <= cell / 2 + 1e-12)
    assert np.all(np.abs(WIN.v) <= WIN.v_max + 1e-9) and np.all(np.abs(WIN.w) <= WIN.w_max + 1e-9)
    assert WIN.v[WIN.stop] == 0 and WIN.w[WIN.stop] == 0
    # a cell straight to the side needs a half turn within one frame: no arc reaches it
    side = int(np.flatnonzero((np.abs(WIN.cell_xy[:, 0]) < 1e-12) & (WIN.cell_xy[:, 1] > 0.01))[0])
    assert side not in set(WIN.cell.tolist())
    # every reachable moving cell is in the cones |heading change| <= w_max T_f
    assert np.all(np.abs(2 * np.arctan2(np.abs(WIN.dy), np.abs(WIN.dx) + 1e-15)[WIN.v != 0]) <= WIN.w_max * WIN.period + 1e-9)


def test_a_wider_turn_rate_opens_the_cones():
    assert C.Window(w_max=4.0).size > WIN.size


def _drive(pose, goal, extra=lambda p: [], frames=2000, tol=0.1):
    """Drive one robot with the survey constraint (and ``extra(pose)``) until it is within ``tol`` of ``goal``."""
    p = np.array(pose, float)[None, :]
    track = [p[0].copy()]
    for i in range(frames):
        if math.dist(p[0, :2], goal) <= tol:
            return i, np.array(track)
        ch = C.choose(WIN, [C.survey(WIN, p, [goal])] + extra(p), 1)
        p = C.advance(p, ch.v, ch.w, WIN.period)
        track.append(p[0].copy())
    return None, np.array(track)


@pytest.mark.parametrize("seed", range(6))
def test_alg2_survey_alone_reaches_the_waypoint_turning_to_face_it(seed):
    rng = np.random.default_rng(seed)
    start = (*rng.uniform(-3, 3, 2), rng.uniform(-math.pi, math.pi))
    goal = tuple(rng.uniform(-3, 3, 2))
    frames, track = _drive(start, goal)
    assert frames is not None
    d = math.dist(start[:2], goal)
    bound = (d / WIN.v_max + math.pi / WIN.w_max) / WIN.period
    assert frames <= 1.3 * bound + 10
    # it turns to face the waypoint rather than reversing to it
    steps = np.diff(track[:, :2], axis=0)
    heading = np.stack([np.cos(track[:-1, 2]), np.sin(track[:-1, 2])], axis=1)
    backward = ((steps * heading).sum(axis=1) < -1e-9).sum()
    assert backward <= 5


def test_alg2_never_forbids_and_weighs_towards_the_waypoint():
    c = C.survey(WIN, [[0, 0, 0]], [[5, 0]])
    assert c.allowed is None
    assert np.argmax(c.height[0]) == int(np.argmax(np.where(WIN.w == 0, WIN.v, -1)))     # straight ahead, full speed
    assert c.height[0, WIN.stop] == pytest.approx(0.0)


LASER = C.Sensor(fov=math.pi, range=8.0)


def test_alg3_a_region_near_the_right_border_forbids_turning_it_further_right():
    """Geometrically: turning clockwise moves a fixed point's bearing counter-clockwise in the sensor frame,
    so a region near the right border (negative bearing) forbids counter-clockwise turns, not clockwise ones
    (the paper's printed rule, read with the usual conventions, has it the other way round: digest §7)."""
    pose = np.array([[0.0, 0.0, 0.0]])
    rot = WIN.v == 0

    def at(deg):
        return [[2 * math.cos(math.radians(deg)), 2 * math.sin(math.radians(deg))]]

    near = C.sensor_view(WIN, pose, at(-75), 0.0, LASER).allowed[0]      # inside the 10 deg margin of the edge
    assert near[rot & (WIN.w < 0)].all() and near[WIN.stop]
    assert not near[rot & (WIN.w > 0)].any()
    past = C.sensor_view(WIN, pose, at(-85), 0.0, LASER).allowed[0]      # drifted into the margin
    assert past[rot & (WIN.w < 0)].all()
    assert not past[WIN.stop] and not past[rot & (WIN.w > 0)].any()      # it must turn back, not wait
    left = C.sensor_view(WIN, pose, at(75), 0.0, LASER).allowed[0]
    assert not left[rot & (WIN.w < 0)].any() and left[rot & (WIN.w > 0)].all()


def test_alg3_a_region_too_far_forbids_moving_away():
    pose = np.array([[0.0, 0.0, 0.0]])
    c = C.sensor_view(WIN, pose, [[7.0, 0.0]], 0.0, LASER)           # beyond 0.8 * 8 m
    assert not c.allowed[0][WIN.v < 0].any() and not c.allowed[0, WIN.stop]
    assert c.allowed[0][(WIN.v > 0) & (WIN.w == 0)].all()


@pytest.mark.parametrize("seed", range(4))
def test_alg3_keeps_a_moving_region_in_view_while_the_robot_surveys_elsewhere(seed):
    """A laser robot pulled by a survey toward random waypoints keeps a slowly wandering region in its field of
    view and range: the region never leaves the view it started in.  The region is another robot's
    surroundings, so it keeps a metre away from this robot (pushed off like a robot avoiding it)."""
    rng = np.random.default_rng(100 + seed)
    p = np.array([[0.0, 0.0, 0.0]])
    region = np.array([3.0, 0.0])
    vel = np.zeros(2)
    goal = rng.uniform(-6, 6, 2)
    worst = 0.0
    for i in range(1500):
        if i % 200 == 0:
            goal = rng.uniform(-6, 6, 2)
        vel = 0.9 * vel + 0.1 * rng.normal(0, 0.1, 2)
        vel *= min(1.0, 0.1 / (np.linalg.norm(vel) + 1e-12))            # region at most 0.1 m/s
        region = region + vel * WIN.period
        off = region - p[0, :2]
        if np.linalg.norm(off) < 1.0:
            region = p[0, :2] + off / np.linalg.norm(off)
        cons = [C.survey(WIN, p, [goal]), C.sensor_view(WIN, p, [region], 0.3, LASER)]
        cons[1].weight = 0.2
        ch = C.choose(WIN, cons, 1)
        assert not ch.conflict[0]
        p = C.advance(p, ch.v, ch.w, WIN.period)
        b, d = C.bearing_distance(p, [region])
        worst = max(worst, abs(float(b[0, 0])))
        assert abs(b[0, 0]) <= LASER.fov / 2 and d[0, 0] + 0.3 <= LASER.range
    assert worst > math.radians(30)          # the survey did pull it around: the constraint had work to do


def test_alg4_forbids_driving_into_an_obstacle_but_not_backing_out():
    pose = np.array([[0.0, 0.0, 0.0]])
    obstacle = np.array([[0.5 + 0.25 + 0.01, 0.0, 0.5]])          # 1 cm ahead of a 0.25 m robot
    c = C.avoid(WIN, pose, obstacle, 0.25)
    ahead = (WIN.v > 0) & (WIN.w == 0)
    assert not c.allowed[0][ahead].any()
    assert c.allowed[0][WIN.v < 0].all() and c.allowed[0, WIN.stop]
    free = C.avoid(WIN, pose, np.array([[5.0, 5.0, 0.5]]), 0.25)
    assert free.allowed[0].all()
    assert free.height[0, WIN.stop] == free.height[0].max()        # far from everything: small moves preferred


@pytest.mark.parametrize("offset", [0.0, 0.05, 0.3, 0.6])
def test_alg4_with_the_survey_goes_round_an_obstacle_without_touching_it(offset):
    obstacle = np.array([[2.0, offset, 0.5]])
    p = np.array([[0.0, 0.0, 0.0]])
    goal = (4.0, 0.0)

    def extra(pose):
        c = C.avoid(WIN, pose, obstacle, 0.25)
        c.weight = 4.0
        return [c]

    frames, track = _drive((0.0, 0.0, 0.0), goal, extra, frames=3000)
    assert frames is not None
    gap = np.hypot(track[:, 0] - 2.0, track[:, 1] - offset) - 0.75
    assert gap.min() >= 0.0


def test_an_empty_intersection_stops_the_robot_and_names_the_conflict():
    fwd = C.band(WIN, 0.24, 0.0, 0.03, 0.5)
    back = C.band(WIN, -0.24, 0.0, 0.03, 0.5)
    fwd.name, back.name = "ahead", "reverse"
    ch = C.choose(WIN, [C.survey(WIN, [[0, 0, 0]], [[3, 0]]), fwd, back], 1)
    assert ch.conflict[0] and ch.v[0] == 0 and ch.w[0] == 0
    assert ch.blame[0] == ["ahead", "reverse"]
    ok = C.choose(WIN, [C.survey(WIN, [[0, 0, 0]], [[3, 0]]), fwd], 1)
    assert not ok.conflict[0] and ok.v[0] > 0.2


def test_a_choice_becomes_arbiter_votes_and_vetoes():
    arcs = ArcSet.uniform(max_speed=0.5, max_reverse=0.2, max_turn_rate=2.0, n_speeds=11, n_turns=21)
    ch = C.choose(WIN, [C.survey(WIN, [[0, 0, 0]], [[3, 0]])], 1)
    votes, veto = C.to_arc_ballot(WIN, ch, arcs)
    assert votes.shape == veto.shape == arcs.v.shape
    assert veto[arcs.v > 0.3].all()                          # beyond the window's top speed
    best = int(np.argmax(np.where(veto, -np.inf, votes)))
    assert arcs.v[best] == pytest.approx(0.25, abs=0.05) and arcs.w[best] == pytest.approx(0.0, abs=0.2)
    assert np.all(np.abs(votes) <= 1.0)
    stop = C.choose(WIN, [C.band(WIN, 0.2, 0, 0.01, 0.1), C.band(WIN, -0.2, 0, 0.01, 0.1)], 1)
    votes, veto = C.to_arc_ballot(WIN, stop, arcs)
    assert (~veto).sum() == 1 and arcs.v[~veto][0] == 0 and arcs.w[~veto][0] == 0


def test_a_window_grid_shows_the_best_candidate_per_cell():
    c = C.survey(WIN, [[0, 0, 0]], [[3, 0]])
    g = WIN.grid(c.height[0])
    assert g.shape == (21, 21)
    assert np.isnan(g[10, 0])                                # straight to the side: unreachable
    assert np.nanargmax(g) == 20 * 21 + 10                   # the cell 5 cm straight ahead


def _fleet_of_16():
    rng = np.random.default_rng(0)
    poses = np.column_stack([rng.uniform(-8, 8, (16, 2)), rng.uniform(-3, 3, 16)])
    obstacles = np.column_stack([poses[:, :2], np.full(16, 0.25)])
    return poses, obstacles, np.eye(16, dtype=bool), rng.uniform(-8, 8, (16, 2))


def test_a_fleet_of_16_in_one_batch_chooses_what_each_robot_alone_does():
    """The batch (what keeps a fleet's cycle in milliseconds: benchmarks/cspace_batch.py measures it against one
    call per robot) changes no robot's choice."""
    poses, obstacles, ignore, goals = _fleet_of_16()
    fleet = C.choose(WIN, [C.survey(WIN, poses, goals), C.avoid(WIN, poses, obstacles, 0.25, ignore)], 16)
    for i in range(16):
        one = C.choose(WIN, [C.survey(WIN, poses[i:i + 1], goals[i:i + 1]),
                             C.avoid(WIN, poses[i:i + 1], obstacles, 0.25, ignore[i:i + 1])], 1)
        assert (one.index[0], one.v[0], one.w[0], one.conflict[0]) == \
            (fleet.index[i], fleet.v[i], fleet.w[i], fleet.conflict[i]), i
