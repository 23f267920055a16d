"""The robot-wide behaviours that vote in the DAMN arbiter (:mod:`runtime.control.arbiter`).

``FollowPath`` votes around the pure-pursuit command; ``AvoidObstacles``, after a bumper hit, backs up and turns
away for a while, and with range readings votes against arcs by how soon they hit and vetoes those that hit within
a short time; ``Stop`` votes to stand still when the path is done or there is none.  Sans-IO: every input takes
``now`` (seconds).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Iterable, Sequence

import numpy as np

from runtime.control import compiled
from runtime.control.arbiter import ArcSet, Ballot, _clip1, _frozen
from runtime.control.pure_pursuit import PurePursuit
from runtime.log import get_logger

log = get_logger("control.behaviours")


@lru_cache(maxsize=16)
def _spread(arcs: ArcSet) -> tuple[float, float]:
    sv = np.ptp(arcs.speeds) if len(arcs.speeds) > 1 else 1.0
    sw = np.ptp(arcs.turn_rates) if len(arcs.turn_rates) > 1 else 1.0
    return float(sv) or 1.0, float(sw) or 1.0


def peak(arcs: ArcSet, v: float, w: float, width: float = 0.15) -> np.ndarray:
    """Votes in [-1, 1] peaking at +1 on (v, w) and falling off as a Gaussian of the distance in arc space
    (each axis scaled by its range; ``width`` is the standard deviation as a fraction of that range)."""
    sv, sw = _spread(arcs)
    if compiled.ENABLED:                  # the exponent compiled, the exponential numpy's own
        e = np.exp(compiled.peak_exponent(arcs.v, arcs.w, float(v), float(w), sv, sw, width ** 2))
        e *= 2.0
        e -= 1.0
        return e
    d2 = ((arcs.v - v) / sv) ** 2 + ((arcs.w - w) / sw) ** 2
    return 2.0 * np.exp(-0.5 * d2 / width ** 2) - 1.0


@dataclass
class FollowPath:
    """Votes for arcs near the pure-pursuit command for the current path and pose."""
    follower: PurePursuit = field(default_factory=PurePursuit)
    weight: float = 1.0
    width: float = 0.15
    name: str = "follow"
    path: list | None = None
    command: tuple[float, float] | None = None
    done: bool = True

    def set_path(self, path: Sequence[Sequence[float]] | None) -> None:
        """Follow ``path`` from now on (None: no path, vote nothing)."""
        self.path = None if path is None else [tuple(p) for p in path]
        self.follower.reset()
        self.command, self.done = None, path is None

    def update(self, pose: tuple[float, float, float], now: float) -> None:
        """New pose estimate: recompute the pure-pursuit command."""
        if self.path is None:
            self.command, self.done = None, True
            return
        v, w, self.done = self.follower.command(pose, self.path)
        self.command = None if self.done else (v, w)

    def ballot(self, arcs: ArcSet, now: float) -> Ballot:
        if self.command is None:
            return Ballot(np.zeros(len(arcs.v)))
        return Ballot(peak(arcs, *self.command, width=self.width))


@dataclass
class Stop:
    """Votes to stand still (and against moving) when the followed path is done or absent."""
    follow: FollowPath
    weight: float = 2.0
    name: str = "stop"

    def ballot(self, arcs: ArcSet, now: float) -> Ballot:
        return Ballot(_stop_votes(arcs, bool(self.follow.done)))


@lru_cache(maxsize=32)
def _stop_votes(arcs: ArcSet, stop: bool) -> np.ndarray:
    """Stop's votes, the same every cycle for an arc set (read-only, computed once)."""
    if not stop:
        return _frozen(np.zeros(len(arcs.v)))
    return _frozen(np.where((arcs.v == 0) & (arcs.w == 0), 1.0, -1.0))


@dataclass
class AvoidObstacles:
    """Obstacle avoidance from bumpers and, when available, range readings (bearing rad, distance m from
    the robot centre, robot frame).

    After a bumper hit: for ``backup_time`` seconds vote for backing up at ``backup_speed`` while turning
    away from the side hit, and veto forward arcs.  Ranges newer than ``range_timeout``: an arc "hits" when
    its path brings the robot within ``radius + margin`` of a reading (and closer to it than now); arcs
    hitting within ``horizon`` seconds get votes from -1 (hit at once) rising to 0 (hit at the horizon),
    and moving arcs hitting within ``veto_time`` are vetoed.  Something in the robot's lane ahead (nearer than its
    goal less a body, within ``ahead_range`` of the clearance) and coming towards it (:meth:`to_pass`) adds a vote for
    curving right, growing as it nears (``keep_right``) and held ``keep_right_hold`` s after the lane clears: robots
    meeting head-on pass each other right to right, robots going the same way follow each other.  Readings that are not finite or negative are dropped and counted in ``dropped``.
    """
    weight: float = 1.5
    radius: float = 0.17
    margin: float = 0.05
    horizon: float = 3.0
    veto_time: float = 0.75
    backup_time: float = 1.0
    backup_speed: float = -0.1
    backup_turn: float = 1.0
    range_timeout: float = 0.5
    max_range: float = 5.0
    keep_right: float = 2.0
    ahead_range: float = 2.0
    keep_right_hold: float = 2.0
    goal_distance: float = math.inf      # m to where the robot is going (set each cycle by whoever drives it)
    speed: float = 0.0                   # m/s the robot moves forward (set each cycle by whoever drives it)
    oncoming_speed: float = 0.05         # m/s: what is dead ahead and comes at the robot this fast or faster is passed
    closing_window: float = 0.5          # s over which how fast the lane ahead closes is judged
    name: str = "avoid"
    dropped: int = 0
    _bump_until: float = field(default=-math.inf, repr=False)
    _turn: float = field(default=0.0, repr=False)
    _pressed: bool = field(default=False, repr=False)
    _points: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)), repr=False)
    _ranges_at: float = field(default=-math.inf, repr=False)
    _ahead: tuple[float, float] = field(default=(0.0, -math.inf), repr=False)
    _gaps: list = field(default_factory=list, repr=False)       # (time, gap ahead) over the closing window
    _lane_memo: tuple | None = field(default=None, repr=False)  # ((points, goal, radius, margin), lane gap)

    def on_bumpers(self, left: bool, right: bool, now: float) -> None:
        """Bumper state: a press starts (or extends) a back-up-and-turn-away manoeuvre."""
        self._pressed = bool(left or right)
        if not self._pressed:
            return
        if left and not right:
            self._turn = -abs(self.backup_turn)      # hit on the left: rotate clockwise (away)
        elif right and not left:
            self._turn = abs(self.backup_turn)
        elif self._turn == 0.0:
            self._turn = -abs(self.backup_turn)      # head-on: keep turning one way
        if now >= self._bump_until:
            log.debug("bump (left=%s right=%s): backing up for %.1f s", left, right, self.backup_time)
        self._bump_until = now + self.backup_time

    def on_ranges(self, readings: Iterable, now: float) -> int:
        """Range readings in the robot frame; returns how many were kept."""
        pts = []
        cos, sin, finite, max_range = math.cos, math.sin, math.isfinite, self.max_range
        for r in readings:
            try:
                bearing, dist = float(r[0]), float(r[1])
            except (TypeError, ValueError, IndexError, KeyError):
                self.dropped += 1
                continue
            if not (finite(bearing) and finite(dist)) or dist < 0:
                self.dropped += 1
                continue
            if dist <= max_range:
                pts.append((dist * cos(bearing), dist * sin(bearing)))
        self._points = np.asarray(pts, dtype=float).reshape(-1, 2)
        self._ranges_at = now
        return len(pts)

    def escape(self, turn: float, duration: float, now: float) -> None:
        """Back up turning at ``turn`` rad/s for ``duration`` s, as after a bump: the way out of a standstill the
        votes cannot leave (two robots stopped nose to nose, each one's path through the other)."""
        self._turn = float(turn)
        self._bump_until = max(self._bump_until, now + duration)

    def backing_up(self, now: float) -> bool:
        """True while the bump manoeuvre runs (bumper pressed, or within backup_time of the last press)."""
        return self._pressed or now < self._bump_until

    def time_to_collision(self, arcs: ArcSet, horizon: float, steps: int = 16) -> np.ndarray:
        """Per arc, the first sampled time within ``horizon`` at which the robot disc reaches a range point.
        Points farther than any arc can take the robot within ``horizon`` (plus the clearance) cannot be hit and
        are left out first.

        A hit is coming within the clearance ``c`` of a point ``p`` while getting closer to it than now: an arc
        that moves away from something already too close stays allowed, so the robot can back out.  The samples
        are not tested one by one: at a given turn rate and time every speed's sample lies on one ray from the
        robot, ``q = v g u`` (unit ``u``, length ``g`` per unit speed), and both conditions, ``|q - p|^2 <= c^2``
        and ``|q - p|^2 < |p|^2 - 1e-12``, hold (as real numbers) for ``(v g - a)^2 <= a^2 + min(c^2 - |p|^2, -1e-12)``
        with ``a = u . p``: an interval of speeds.  So a cycle costs (turn rates x steps x points) intervals (only
        where ``m >= 0`` can hold one: those are counted against the speeds) and a bitmask of the speeds hit per
        (turn rate, time) row, not (arcs x steps x points) distances."""
        pts = self._points
        if len(pts) == 0:
            return np.full(len(arcs.v), np.inf)
        k = _arc_rays(arcs, float(horizon), int(steps))
        clearance = self.radius + self.margin
        reach = k.reach + clearance
        if compiled.ENABLED:                  # the same intervals, each speed's first hit kept as it is found
            pts, lim = compiled.near_points(pts, reach, clearance * clearance)
            if len(pts) == 0:
                return np.full(len(arcs.v), np.inf)
            return compiled.first_hits(k.rays @ pts.T, lim, k.g, k.speeds, k.first, k.nw, k.steps)
        d2 = (pts * pts).sum(axis=1)
        near = d2 <= reach * reach
        if not near.any():
            return np.full(len(arcs.v), np.inf)
        pts, d2 = pts[near], d2[near]
        a = k.rays @ pts.T                                            # (nw * steps, points)
        m = a * a + np.minimum(clearance * clearance - d2, -1e-12)
        at = np.flatnonzero(m.ravel() >= 0)                           # only these can hold an interval
        rows = at // len(pts)
        a, root, g = a.ravel()[at], np.sqrt(np.maximum(m.ravel()[at], 0.0)), k.g[rows]
        lo = k.speeds.searchsorted((a - root) / g, side="left")      # first speed in the interval ...
        hi = k.speeds.searchsorted((a + root) / g, side="right")     # ... and one past the last
        if k.nv <= _WORD:
            steps_hit = _steps_hit(k, rows, lo, hi)[:, :k.nv]
        else:                                                         # speeds in words of _WORD
            steps_hit = np.concatenate([_steps_hit(k, rows, np.clip(lo - s, 0, _WORD), np.clip(hi - s, 0, _WORD))
                                        for s in range(0, k.nv, _WORD)], axis=1)[:, :k.nv]
        return k.first[steps_hit].T.ravel()                           # (nw, nv) -> arc order (speed-major)

    def ballot(self, arcs: ArcSet, now: float) -> Ballot:
        n = len(arcs.v)
        m = _arc_masks(arcs)
        votes, veto = np.zeros(n), np.zeros(n, dtype=bool)
        if self.backing_up(now):
            votes = peak(arcs, self.backup_speed, self._turn, width=0.2)
            votes = np.where(m.forward, -1.0, votes)
            veto |= m.forward
        if now - self._ranges_at <= self.range_timeout and len(self._points):
            ttc = self.time_to_collision(arcs, self.horizon, steps=24)
            if compiled.ENABLED:
                ahead = self._keep_right_ahead(now)
                keep = ahead > 0 and self.keep_right > 0
                compiled.range_votes(votes, veto, ttc, m.moving, m.right, self.veto_time, self.horizon, keep,
                                     ahead * self.keep_right)
                return Ballot(votes, veto)
            veto |= (ttc <= self.veto_time) & m.moving
            hits = np.isfinite(ttc)
            votes = np.where(hits, np.minimum(votes, -(1.0 - ttc / self.horizon)), votes)
            ahead = self._keep_right_ahead(now)
            if ahead > 0 and self.keep_right > 0:
                votes = votes - ahead * self.keep_right * m.right
        return Ballot(_clip1(votes), veto)

    def _keep_right_ahead(self, now: float) -> float:
        """How close what is to be passed on the right is (0: nothing to pass), as :meth:`dead_ahead`, held
        ``keep_right_hold`` s once the pass began."""
        ahead = self.dead_ahead()
        if ahead > 0 and self.to_pass(now):
            self._ahead = (ahead, now)
        elif now - self._ahead[1] <= self.keep_right_hold:
            ahead = self._ahead[0]              # held: turning right clears the lane, the pass is not done
        else:
            ahead = 0.0                         # what is ahead goes our way, or stands: follow it, do not pass
        return ahead

    def to_pass(self, now: float) -> bool:
        """Whether what is dead ahead is to be passed on the right: it comes towards the robot at ``oncoming_speed``
        or more, judged from how fast the gap to it closed over the last ``closing_window`` s beside the robot's own
        ``speed`` (False until the lane has been watched that long).  A robot ahead going the same way (the next one
        on a transport circuit) or standing (working at a mark) is followed, not overtaken: range votes keep the
        distance, and a standstill that lasts is the executive's stall escape.  Overtaking on the right pushed
        robots off their lane into the oncoming one, and two robots standing nose to nose, each keeping right
        while its path follower turned it back, dithered for good."""
        gap = self._lane_gap()
        if not math.isfinite(gap):
            self._gaps = []
            return False
        self._gaps = [g for g in self._gaps if now - g[0] <= self.closing_window] + [(now, gap)]
        t0, g0 = self._gaps[0]
        if now - t0 < 0.6 * self.closing_window:
            return False
        closing = (g0 - gap) / (now - t0)
        return closing - self.speed >= self.oncoming_speed

    def _lane_gap(self) -> float:
        """Distance from the clearance to the nearest range point in the robot's lane ahead (inf: none), leaving
        out what stands within a body of the goal."""
        pts = self._points
        if len(pts) == 0:
            return math.inf
        key = (pts, self.goal_distance, self.radius, self.margin)
        cached = self._lane_memo
        if cached is not None and cached[0][0] is pts and cached[0][1:] == key[1:]:
            return cached[1]     # the same readings and goal as the last call this cycle (dead_ahead, to_pass)
        gap = self._lane_gap_of(pts)
        self._lane_memo = (key, gap)
        return gap

    def _lane_gap_of(self, pts: np.ndarray) -> float:
        clearance = self.radius + self.margin
        if compiled.ENABLED:
            return compiled.lane_gap(pts, clearance, self.goal_distance - 2 * self.radius)
        lane = (pts[:, 0] > 0) & (np.abs(pts[:, 1]) < clearance) & (pts[:, 0] < self.goal_distance - 2 * self.radius)
        if not lane.any():
            return math.inf
        return float(np.min(pts[lane, 0])) - clearance

    def dead_ahead(self) -> float:
        """How close the nearest range point in the robot's lane ahead is: 0 (none within ``ahead_range`` of
        the clearance) to 1 (at the clearance).  Something dead ahead makes the robot keep right, as road traffic
        does: two robots meeting head-on both veer to their right and pass, where votes that only penalise the
        arcs towards each other leave both facing each other, stopped (each one's path runs through the other).
        What stands at the goal (within a body of it: a robot at the same mark) is waited for, not passed."""
        gap = self._lane_gap()
        if not math.isfinite(gap):
            return 0.0
        return float(min(max(1.0 - gap / self.ahead_range, 0.0), 1.0))


@dataclass(frozen=True)
class _Masks:
    """What :meth:`AvoidObstacles.ballot` needs of an arc set every cycle, computed once (read-only)."""
    forward: np.ndarray       # arcs.v > 0
    moving: np.ndarray        # arcs.v != 0
    right: np.ndarray         # keep-right direction per arc: w / max |w| on forward arcs, 0 elsewhere


@lru_cache(maxsize=16)
def _arc_masks(arcs: ArcSet) -> _Masks:
    wmax = float(np.max(np.abs(arcs.w))) or 1.0
    return _Masks(_frozen(arcs.v > 0), _frozen(arcs.v != 0), _frozen(np.where(arcs.v > 0, arcs.w / wmax, 0.0)))


@dataclass(frozen=True)
class _Rays:
    """What :meth:`AvoidObstacles.time_to_collision` needs of an arc set, horizon and step count."""
    rays: np.ndarray          # (nw * steps, 2): unit direction of every speed's sample, per (turn rate, time) row
    g: np.ndarray             # (nw * steps,): sample length per unit speed (the sample of speed v is v g u)
    speeds: np.ndarray        # the sorted speed axis
    bit: np.ndarray           # uint64 2**i for i in 0.._WORD: the speeds in [lo, hi) are bit[hi] - bit[lo]
    first: np.ndarray         # time of the first hit by how many of the steps hit: [inf, t[-1], ..., t[0]]
    reach: float              # farthest any arc goes within the horizon
    nv: int
    nw: int
    steps: int
    count: type               # dtype that counts steps


_WORD = 63                # speeds per word of bits


def _steps_hit(k: "_Rays", rows: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(nw, _WORD): per turn rate and speed (within a word, lo and hi in 0.._WORD), how many of the steps hit,
    given intervals [lo, hi) of speeds hit in rows (turn rate, step; ascending).  Each row's speeds hit become bits (speed i:
    bit i; an empty interval adds none); OR along the steps gives the speeds hit by each step, and as that only
    grows, the steps with a speed's bit set count back from the last to its first hit."""
    hit = np.zeros(len(k.rays), dtype=np.uint64)
    if len(rows):                         # rows ascend: OR each run of equal rows at once (ufunc.at is slow)
        starts = np.flatnonzero(np.concatenate(([True], rows[1:] != rows[:-1])))
        hit[rows[starts]] = np.bitwise_or.reduceat(k.bit[hi] - k.bit[lo], starts)
    by_then = np.bitwise_or.accumulate(hit.reshape(k.nw, k.steps), axis=1).astype("<u8", copy=False)
    bits = np.unpackbits(np.ascontiguousarray(by_then.T).view(np.uint8).reshape(k.steps, k.nw * 8), axis=1,
                         bitorder="little")
    return np.add.reduce(bits, axis=0, dtype=k.count).reshape(k.nw, 64)[:, :_WORD]


@lru_cache(maxsize=16)
def _arc_rays(arcs: ArcSet, horizon: float, steps: int) -> _Rays:
    """Sample times in (0, horizon] and, per (turn rate, time) row, the unit direction from the robot (robot frame)
    on which every speed's sample lies and its length per unit speed (the sample of speed v is ``v g u``), and
    the sorted speeds; computed once per arc set, horizon and step count."""
    nv, nw = arcs.shape
    t = np.linspace(horizon / steps, horizon, steps)
    w = np.asarray(arcs.turn_rates)[:, None]
    th = w * t
    small = np.abs(w) < 1e-9
    safe_w = np.where(small, 1.0, w)
    ux = np.where(small, t, np.sin(th) / safe_w).ravel()
    uy = np.where(small, 0.0, (1 - np.cos(th)) / safe_w).ravel()
    g = np.hypot(ux, uy)
    home = g < 1e-12                      # a full turn: every speed's sample is back at the start, hitting nothing
    g = np.where(home, 1.0, g)
    rays = np.where(home[:, None], 0.0, np.column_stack((ux / g, uy / g)))
    bit = np.left_shift(np.uint64(1), np.arange(_WORD + 1, dtype=np.uint64))
    first = np.concatenate(([np.inf], t[::-1]))
    reach = float(np.max(np.abs(arcs.v))) * horizon
    return _Rays(_frozen(rays), _frozen(g), _frozen(np.asarray(arcs.speeds, dtype=float)), _frozen(bit),
                 _frozen(first), reach, nv, nw, steps,
                 np.uint8 if steps < 256 else np.intp)
