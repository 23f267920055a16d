"""The compiled kernels (runtime/control/compiled.py, numba) give the numpy code's results bit for bit: time to
collision, the avoidance ballot, the arbiter's decision and the pure-pursuit projection, on random inputs that
reach their edges (points inside the clearance, NaN and inf votes, every arc vetoed, paths the robot leaves)."""
import math

import numpy as np
import pytest

from runtime.control import compiled
from runtime.control.arbiter import Arbiter, ArcSet, Ballot
from runtime.control.behaviours import AvoidObstacles, FollowPath, Stop, peak
from runtime.control.pure_pursuit import PurePursuit

pytestmark = pytest.mark.skipif(not compiled.AVAILABLE, reason="numba not installed (the fast extra)")


@pytest.fixture(autouse=True)
def _kernels_on(monkeypatch):
    monkeypatch.setattr(compiled, "ENABLED", True)       # as a host that enables them (runtime.inprocess.Fleet)

ARC_SETS = (ArcSet.uniform(max_speed=0.25, max_reverse=0.2, max_turn_rate=2.0),     # the foraging robots'
            ArcSet.uniform(max_speed=0.5, max_reverse=0.0, n_speeds=70, n_turns=9))   # more speeds than a word


def both(monkeypatch, call):
    """``call()`` with the kernels, then with the numpy code."""
    fast = call()
    monkeypatch.setattr(compiled, "ENABLED", False)
    try:
        slow = call()
    finally:
        monkeypatch.setattr(compiled, "ENABLED", True)
    return fast, slow


def same(a, b) -> bool:
    a, b = np.atleast_1d(np.asarray(a)), np.atleast_1d(np.asarray(b))
    return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a.view(np.uint8), b.view(np.uint8))


def points(rng, n):
    """Range points around the robot, some inside its clearance, some out of any arc's reach."""
    scale = rng.choice([0.3, 1.0, 3.0])
    return rng.normal(size=(n, 2)) * scale


def test_time_to_collision_and_the_avoidance_ballot_match_numpy(monkeypatch):
    rng = np.random.default_rng(35)
    for trial in range(300):
        arcs = ARC_SETS[trial % 2]
        avoid = AvoidObstacles(radius=float(rng.uniform(0.1, 0.3)), margin=float(rng.uniform(0.0, 0.1)))
        avoid._points = points(rng, int(rng.integers(0, 20)))
        fast, slow = both(monkeypatch, lambda: avoid.time_to_collision(arcs, 3.0, steps=24))
        assert same(fast, slow), trial
        now = float(trial)
        avoid._ranges_at = now
        if trial % 3 == 0:
            avoid.on_bumpers(bool(rng.integers(2)), bool(rng.integers(2)), now)
        avoid.goal_distance = float(rng.choice([math.inf, rng.uniform(0.2, 3.0)]))
        avoid._ahead = (float(rng.uniform(0, 1)), now - float(rng.uniform(0, 3)))    # a pass held, or not
        state = dict(avoid.__dict__)

        def ballot():
            avoid.__dict__.update(state)
            avoid._gaps, avoid._lane_memo = list(state["_gaps"]), None
            b = avoid.ballot(arcs, now)
            return b.votes, b.veto, avoid._lane_gap()
        (fv, fveto, fgap), (sv, sveto, sgap) = both(monkeypatch, ballot)
        assert same(fv, sv) and same(fveto, sveto) and same(fgap, sgap), trial


class Fixed:
    """A behaviour whose ballot is given."""

    def __init__(self, ballot, weight):
        self.name, self.weight, self._ballot = "fixed", weight, ballot

    def ballot(self, arcs, now):
        return self._ballot


def test_arbiter_decisions_match_numpy_with_nan_inf_and_vetoes(monkeypatch):
    rng = np.random.default_rng(36)
    arcs = ARC_SETS[0]
    n = len(arcs.v)
    for trial in range(300):
        behaviours = []
        for _ in range(int(rng.integers(1, 4))):
            votes = rng.uniform(-1.5, 1.5, n)
            spoil = rng.random(n) < 0.02 * (trial % 4)
            votes[spoil] = rng.choice([np.nan, np.inf, -np.inf, 0.0, -0.0], spoil.sum())
            veto = None if rng.random() < 0.3 else rng.random(n) < rng.choice([0.0, 0.5, 1.0])
            behaviours.append(Fixed(Ballot(votes, veto), float(rng.choice([0.0, 1.0, 1.5, 2.0]))))
        arbiter = Arbiter(arcs, behaviours, smoothing=float(rng.choice([0.0, 1.0])))

        def decide():
            d = arbiter.decide(0.0)
            return d.v, d.w, d.arc, d.scores, arbiter.vetoed_all
        fast, slow = both(monkeypatch, decide)
        arbiter.vetoed_all = 0
        assert fast[:3] == slow[:3] and same(fast[3], slow[3]), trial
    follow = FollowPath()
    follow.set_path([(0.0, 0.0), (2.0, 1.0)])
    follow.update((0.1, 0.0, 0.3), 0.0)
    arbiter = Arbiter(arcs, [follow, AvoidObstacles(), Stop(follow)])
    fast, slow = both(monkeypatch, lambda: arbiter.decide(0.0))
    assert (fast.v, fast.w, fast.arc) == (slow.v, slow.w, slow.arc) and same(fast.scores, slow.scores)


def test_pure_pursuit_matches_numpy_along_random_paths(monkeypatch):
    rng = np.random.default_rng(37)
    for trial in range(60):
        path = np.cumsum(rng.normal(size=(int(rng.integers(2, 9)), 2)), axis=0).tolist()
        if trial % 5 == 0:
            path.insert(1, list(path[0]))                        # a zero-length segment
        follower = {True: PurePursuit(lookahead=0.3), False: PurePursuit(lookahead=0.3)}
        pose = [path[0][0] + float(rng.normal(0, 0.3)), path[0][1], 0.0]
        for step in range(60):
            if step % 7 == 6:                                    # pushed off the path, near and far
                jump = float(rng.choice([0.1, 0.3, 1.0, 3.0]))
                pose[:2] = (pose[0] + float(rng.normal(0, jump)), pose[1] + float(rng.normal(0, jump)))
            out = {}
            for fast in (True, False):
                compiled.ENABLED = fast
                try:
                    out[fast] = follower[fast].command(tuple(pose), path), follower[fast]._progress
                finally:
                    compiled.ENABLED = True
            assert out[True] == out[False], (trial, step)
            v, w, done = out[True][0]
            if done:
                break
            pose[2] += w * 0.1
            pose[0] += v * 0.1 * math.cos(pose[2])
            pose[1] += v * 0.1 * math.sin(pose[2])


def test_pure_pursuit_window_edge_matches_numpy(monkeypatch):
    """Just inside and just outside the look-ahead of the window around progress, with a later leg nearer."""
    path = [(0.0, 0.0), (2.0, 0.0), (2.0, 0.5), (0.0, 0.5)]
    for y in np.linspace(0.25, 0.35, 41):
        def project():
            p = PurePursuit(lookahead=0.3)
            p.command((0.0, 0.0, 0.0), path)
            p._progress = 0.5
            return p._project(0.5, float(y))
        fast, slow = both(monkeypatch, project)
        assert fast == slow, y


def test_peak_matches_numpy(monkeypatch):
    rng = np.random.default_rng(38)
    for trial in range(100):
        arcs = ARC_SETS[trial % 2]
        v, w, width = float(rng.uniform(-0.3, 0.6)), float(rng.uniform(-3, 3)), float(rng.choice([0.15, 0.2, 1.0]))
        fast, slow = both(monkeypatch, lambda: peak(arcs, v, w, width=width))
        assert same(fast, slow), trial


def test_a_host_of_many_robots_turns_the_kernels_on_and_numpy_code_holds_them_off(monkeypatch):
    from runtime.inprocess import kinematic
    monkeypatch.setattr(compiled, "ENABLED", False)             # as in a daemon's process
    with compiled.numpy_code():
        kinematic({1: (0.0, 0.0)}, method="auction")
        assert not compiled.ENABLED
    kinematic({1: (0.0, 0.0)}, method="auction")
    assert compiled.ENABLED


def test_the_sitl_sonar_ring_matches_numpy_for_packed_and_scattered_robots(monkeypatch):
    """The foraging world's closed-form sonar (sitl/sensing/sonar_ring.py): robots scattered over the arena, packed
    so their discs touch and overlap, alone, and against the walls."""
    from sitl.sensing import sonar_ring as S
    rng = np.random.default_rng(11)
    for trial in range(600):
        n = int(rng.integers(1, 12))
        spread = (6.0, 0.6, 6.4)[trial % 3]
        poses = np.column_stack((rng.uniform(-spread, spread, (n, 2)), rng.uniform(-4, 4, n)))
        fast, slow = both(monkeypatch, lambda: S.ring_ranges(poses, 0.25, 6.5))
        assert same(fast, slow), (trial, poses)
        assert fast.shape == (n, S.N_SONARS) and (fast <= S.MAX_RANGE).all()
