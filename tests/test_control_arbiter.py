"""DAMN-style arbiter: vote summing, smoothing, vetoes, and the follow / avoid / stop behaviours."""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from runtime.control.arbiter import Arbiter, ArcSet, Ballot
from runtime.control.behaviours import AvoidObstacles, FollowPath, Stop, peak
from runtime.control.pure_pursuit import PurePursuit
from runtime.errors import InputError

ARCS = ArcSet.uniform(max_speed=0.5, max_reverse=0.2, max_turn_rate=2.0, n_speeds=11, n_turns=21)
PATH = [(0.0, 0.0), (3.0, 0.0), (3.0, 2.0)]


def make():
    follow = FollowPath(PurePursuit(lookahead=0.4, cruise_speed=0.3, max_turn_rate=2.0, goal_tolerance=0.05))
    avoid = AvoidObstacles()
    arb = Arbiter(ARCS, [follow, avoid, Stop(follow)])
    return follow, avoid, arb


def test_arc_set_layout():
    assert ARCS.speeds[0] == pytest.approx(-0.2) and 0.0 in ARCS.speeds and ARCS.speeds[-1] == 0.5
    assert ARCS.shape == (15, 21) and len(ARCS.v) == 15 * 21
    k = ARCS.nearest(0.31, -0.62)
    assert (ARCS.v[k], ARCS.w[k]) == (pytest.approx(0.3), pytest.approx(-0.6))
    for bad in (dict(speeds=(0.1, 0.2), turn_rates=(0.0,)), dict(speeds=(0.0, 0.0), turn_rates=(0.0,)),
                dict(speeds=(0.0,), turn_rates=(math.nan,))):
        with pytest.raises(InputError):
            ArcSet(**bad)


def test_no_obstacle_picks_the_follow_command():
    follow, _, arb = make()
    follow.set_path(PATH)
    for pose in [(0.0, 0.0, 0.0), (1.0, 0.2, 0.3), (2.8, 0.1, 1.2), (2.0, -0.3, -0.4)]:
        follow.update(pose, now=0.0)
        v, w = follow.command
        d = arb.decide(now=0.0)
        assert d.arc == ARCS.nearest(v, w), (pose, (v, w), (d.v, d.w))


def test_bump_backs_off_turning_away_then_resumes():
    follow, avoid, arb = make()
    follow.set_path(PATH)
    follow.update((0.5, 0.0, 0.0), now=10.0)
    assert arb.decide(10.0).v > 0
    avoid.on_bumpers(left=True, right=False, now=10.0)
    d = arb.decide(10.0)
    assert d.v < 0 and d.w < 0                     # back up, rotating clockwise away from the left hit
    avoid.on_bumpers(left=False, right=False, now=10.1)
    assert arb.decide(10.5).v < 0                  # keeps backing for backup_time after release
    avoid.on_bumpers(left=False, right=True, now=20.0)
    d = arb.decide(20.0)
    assert d.v < 0 and d.w > 0
    avoid.on_bumpers(False, False, 20.05)
    assert arb.decide(21.5).v > 0                  # manoeuvre over: following again


def test_stop_when_done_or_without_path():
    follow, _, arb = make()
    follow.set_path(None)
    assert (arb.decide(0.0).v, arb.decide(0.0).w) == (0.0, 0.0)
    follow.set_path(PATH)
    follow.update((3.0, 2.0 - 0.01, 1.57), now=1.0)
    assert follow.done
    d = arb.decide(1.0)
    assert (d.v, d.w) == (0.0, 0.0)


def test_range_obstacle_ahead_vetoes_straight_arcs():
    follow, avoid, arb = make()
    follow.set_path([(0.0, 0.0), (5.0, 0.0)])
    follow.update((0.0, 0.0, 0.0), now=0.0)
    avoid.on_ranges([(0.0, 1.0)], now=0.0)
    far = avoid.ballot(ARCS, 0.0)
    straight = ARCS.nearest(0.3, 0.0)
    assert not far.veto.any() and -1 < far.votes[straight] < 0          # hit in ~2.6 s: disliked only
    avoid.on_ranges([(0.0, 0.35), (0.05, 0.35), (-0.05, 0.35)], now=0.0)
    d = arb.decide(0.0)
    ballot = avoid.ballot(ARCS, 0.0)
    assert ballot.veto[straight] and not ballot.veto[d.arc]
    assert ballot.votes[straight] < far.votes[straight]
    assert np.isneginf(d.scores[straight])
    assert not (d.v > 0 and abs(d.w) < 0.3)
    # Stale readings are ignored.
    assert arb.decide(5.0).arc == ARCS.nearest(*follow.command)


def test_moving_away_from_a_too_close_point_is_allowed():
    avoid = AvoidObstacles()
    avoid.on_ranges([(0.0, 0.1)], now=0.0)          # already inside the clearance, dead ahead
    b = avoid.ballot(ARCS, 0.0)
    assert b.veto[ARCS.nearest(0.3, 0.0)] and not b.veto[ARCS.nearest(-0.2, 0.0)]


def test_all_vetoed_stands_still_and_counts():
    class VetoAll:
        name, weight = "veto", 1.0

        def ballot(self, arcs, now):
            return Ballot(np.ones(len(arcs.v)), np.ones(len(arcs.v), bool))
    arb = Arbiter(ARCS, [VetoAll()])
    d = arb.decide(0.0)
    assert (d.v, d.w, arb.vetoed_all) == (0.0, 0.0, 1)


def test_gaussian_smoothing_prefers_a_broad_good_region_over_a_lone_spike():
    class Votes:
        def __init__(self, votes):
            self.name, self.weight, self.votes = "v", 1.0, votes

        def ballot(self, arcs, now):
            return Ballot(self.votes)
    lone = ARCS.nearest(0.3, -1.0)
    broad = peak(ARCS, 0.3, 1.0, width=0.2) * 0.45 + 0.45
    votes = broad.copy()
    votes[lone] = 1.0
    votes[[lone - 1, lone + 1]] = -1.0
    assert Arbiter(ARCS, [Votes(votes)], smoothing=0).decide(0).arc == lone
    assert Arbiter(ARCS, [Votes(votes)], smoothing=1.0).decide(0).w > 0


def test_weights_scale_influence():
    class Want:
        def __init__(self, v, w, weight):
            self.name, self.weight, self.cmd = "want", weight, (v, w)

        def ballot(self, arcs, now):
            return Ballot(peak(arcs, *self.cmd))
    arb = Arbiter(ARCS, [Want(0.3, 1.0, 1.0), Want(0.3, -1.0, 2.0)])
    assert arb.decide(0).w < 0
    with pytest.raises(InputError):
        Arbiter(ARCS, [Want(0, 0, -1.0)])


reading = st.one_of(
    st.tuples(st.floats(allow_nan=True, allow_infinity=True), st.floats(allow_nan=True, allow_infinity=True)),
    st.tuples(st.floats(-4, 4), st.floats(0, 6)),
    st.tuples(st.floats(-4, 4)),                                    # truncated
    st.text(max_size=3), st.none(), st.integers())


@settings(max_examples=200, deadline=None)
@given(readings=st.lists(reading, max_size=30))
def test_range_input_never_raises_and_counts_drops(readings):
    avoid = AvoidObstacles(max_range=5.0)
    kept = avoid.on_ranges(readings, now=0.0)

    def distance(r):
        try:
            b, d = float(r[0]), float(r[1])
        except (TypeError, ValueError, IndexError, KeyError):
            return None
        return d if math.isfinite(b) and math.isfinite(d) and d >= 0 else None
    dists = [distance(r) for r in readings]
    assert avoid.dropped == sum(d is None for d in dists)
    assert kept == sum(d is not None and d <= 5.0 for d in dists)
    b = avoid.ballot(ARCS, 0.0)
    assert np.all(np.abs(b.votes) <= 1.0) and b.veto.shape == b.votes.shape


def unicycle(pose, v, w, dt):
    x, y, th = pose
    return x + v * math.cos(th) * dt, y + v * math.sin(th) * dt, th + w * dt


def test_closed_loop_reaches_goal_around_an_unmapped_obstacle():
    """Path straight through a post the planner did not know; range votes steer round it."""
    follow, avoid, arb = make()
    follow.set_path([(0.0, 0.0), (4.0, 0.0)])
    post = np.array([2.0, 0.05])
    pose, dt, closest = (0.0, 0.0, 0.0), 0.05, math.inf
    for k in range(1600):
        now = k * dt
        rel = post - pose[:2]
        dist = float(np.hypot(*rel))
        closest = min(closest, dist)
        bearing = math.atan2(rel[1], rel[0]) - pose[2]
        avoid.on_ranges([(bearing, dist - 0.05)] if dist < 2.0 else [], now)   # a 5 cm radius post
        follow.update(pose, now)
        d = arb.decide(now)
        if follow.done:
            break
        pose = unicycle(pose, d.v, d.w, dt)
    assert follow.done and math.hypot(pose[0] - 4.0, pose[1]) <= 0.05
    assert closest > 0.17 + 0.05                    # robot radius + post radius: never touched


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 40), sigma=st.floats(0.3, 4.0), seed=st.integers(0, 2 ** 32 - 1))
def test_smoothing_matrix_is_scipys_gaussian_filter_with_nearest_edges(n, sigma, seed):
    from scipy import ndimage
    from runtime.control.arbiter import smoothing_matrix
    x = np.random.default_rng(seed).normal(size=n)
    want = ndimage.gaussian_filter1d(x, sigma, mode="nearest")
    assert np.allclose(smoothing_matrix(n, sigma) @ x, want, rtol=0, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), sigma=st.sampled_from([0.5, 1.0, 2.0]))
def test_decide_scores_equal_the_2d_gaussian_filter_of_the_weighted_votes(seed, sigma):
    from scipy import ndimage
    rng = np.random.default_rng(seed)
    arcs = ArcSet.uniform()

    class Random:
        name, weight = "random", 1.0

        def __init__(self):
            self.votes = rng.uniform(-1.5, 1.5, len(arcs.v))
            self.votes[rng.random(len(arcs.v)) < 0.05] = np.nan

        def ballot(self, arcs, now):
            return Ballot(self.votes)

    bs = [Random(), Random()]
    d = Arbiter(arcs, bs, smoothing=sigma).decide(0.0)
    total = sum(np.clip(np.nan_to_num(b.votes, nan=0.0), -1, 1) for b in bs)
    want = ndimage.gaussian_filter(total.reshape(arcs.shape), sigma, mode="nearest").ravel()
    assert np.allclose(d.scores, want, rtol=0, atol=1e-12)
    assert d.arc == int(np.argmax(want))


def _approach(avoid, arcs, start: float, closing: float, speed: float, cycles: int = 8):
    """One reading dead ahead, ``start`` m off and closing at ``closing`` m/s, the robot driving at ``speed``; the
    last ballot's votes."""
    avoid.speed = speed
    for k in range(cycles):
        avoid.on_ranges([(0.0, start - closing * 0.1 * k)], 0.1 * k)
        votes = avoid.ballot(arcs, 0.1 * k).votes
    return votes


def test_something_coming_head_on_votes_for_curving_right_and_the_vote_is_held():
    arcs = ArcSet.uniform(max_speed=0.25, max_turn_rate=2.0)
    avoid = AvoidObstacles(radius=0.25)
    votes = _approach(avoid, arcs, 1.5, closing=0.4, speed=0.2)      # it comes at us at 0.2 m/s
    assert avoid.dead_ahead() > 0
    right, left = arcs.nearest(0.2, -1.0), arcs.nearest(0.2, 1.0)
    assert votes[right] > votes[left]
    avoid.on_ranges([(0.0, 5.0)], 1.0)                          # lane clear: still held ...
    assert avoid.ballot(arcs, 1.0).votes[right] > avoid.ballot(arcs, 1.0).votes[left]
    avoid.on_ranges([(0.0, 5.0)], 4.0)                          # ... for keep_right_hold s only
    v = avoid.ballot(arcs, 4.0).votes
    assert v[right] == v[left]


def test_what_goes_our_way_or_stands_is_followed_not_passed():
    arcs = ArcSet.uniform(max_speed=0.25, max_turn_rate=2.0)
    right, left = arcs.nearest(0.2, -1.0), arcs.nearest(0.2, 1.0)
    coming = _approach(AvoidObstacles(radius=0.25), arcs, 1.5, closing=0.3, speed=0.2)   # comes at 0.1 m/s
    assert coming[right] > coming[left] + 0.5
    for closing in (0.2, 0.0):                                  # stands; goes as fast as we do
        ahead = _approach(AvoidObstacles(radius=0.25), arcs, 1.5, closing=closing, speed=0.2)
        assert ahead[right] == pytest.approx(ahead[left], abs=1e-9)
    first = AvoidObstacles(radius=0.25)                          # not watched long enough to judge: no vote yet
    first.on_ranges([(0.0, 1.2)], 0.0)
    v = first.ballot(arcs, 0.0).votes
    assert first.dead_ahead() > 0 and v[right] == pytest.approx(v[left], abs=1e-9)


def test_what_stands_at_the_goal_is_not_passed():
    avoid = AvoidObstacles(radius=0.25)
    avoid.on_ranges([(0.0, 1.0)], 0.0)
    avoid.goal_distance = 1.2                                   # the point is on the goal's doorstep
    assert avoid.dead_ahead() == 0.0
    avoid.goal_distance = 3.0
    assert avoid.dead_ahead() > 0


_MIDS = tuple(tuple((a + b) / 2 for a, b in zip(axis, axis[1:])) for axis in (ARCS.speeds, ARCS.turn_rates))


@settings(max_examples=200, deadline=None)
@given(v=st.one_of(st.floats(-1.0, 1.0), st.sampled_from(ARCS.speeds + _MIDS[0]), st.floats(width=64)),
       w=st.one_of(st.floats(-3.0, 3.0), st.sampled_from(ARCS.turn_rates + _MIDS[1]), st.floats(width=64)))
def test_nearest_is_the_first_argmin_of_the_distance_on_each_axis(v, w):
    # arc values, midpoints between neighbours (ties: the first wins), NaN and infinities included
    iv = int(np.argmin(np.abs(np.asarray(ARCS.speeds) - v)))
    iw = int(np.argmin(np.abs(np.asarray(ARCS.turn_rates) - w)))
    assert ARCS.nearest(v, w) == iv * len(ARCS.turn_rates) + iw
    assert ARCS.nearest(np.float64(v), np.float64(w)) == iv * len(ARCS.turn_rates) + iw      # numpy scalars too
