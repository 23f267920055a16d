"""MobileBase's shared policy on a tiny fake driver: finite check, clipping that keeps the curvature,
the command watchdog, the lifecycle and the counters."""
from __future__ import annotations

import logging
import math

import pytest
from hypothesis import example, given, settings, strategies as st

from runtime.drivers.base import Footprint, MobileBase
from runtime.errors import InputError
from runtime.log import get_logger

CREATE2 = Footprint(radius=0.17, track=0.235, max_speed=0.5, max_turn_rate=2 * 0.5 / 0.235)
SLOW_TURN = Footprint(radius=0.3, track=0.4, max_speed=1.0, max_turn_rate=1.0)   # 2 v/track would be 5


class FakeBase(MobileBase):
    """Records what the policy hands the driver; "moves" on any non-zero command."""

    def __init__(self, footprint=CREATE2, watchdog=0.5):
        super().__init__(footprint, watchdog, get_logger("test.fakebase", 7))
        self.sent: list[tuple[float, float, float]] = []
        self.reads: list[float] = []
        self.opened = self.closed = 0
        self.fresh = True

    def _open(self, now):
        self.opened += 1

    def _close(self):
        self.closed += 1

    def _read(self, now):
        self.reads.append(now)
        return self.fresh

    def _command(self, v, w, now):
        self.sent.append((v, w, now))
        return (v, w) != (0.0, 0.0)


def opened(**kw) -> FakeBase:
    b = FakeBase(**kw)
    b.open(0.0)
    return b


def wheel_peak(fp: Footprint, v: float, w: float) -> float:
    return abs(v) + abs(w) * fp.track / 2


speeds = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                   st.floats(-5.0, 5.0), st.floats(-50.0, 50.0), st.sampled_from([0.0, -0.0, 0.5, -0.5]))


# ----------------------------------------------------------------------------- finite check and clipping
@settings(max_examples=400, deadline=None)
@given(fp=st.sampled_from([CREATE2, SLOW_TURN]), v=speeds, w=speeds)
@example(fp=CREATE2, v=math.nan, w=0.1)
@example(fp=CREATE2, v=0.1, w=-math.inf)
@example(fp=CREATE2, v=1e308, w=1e308)
@example(fp=CREATE2, v=1.6086739461855175e+308, w=1.6086739461855173e+308)   # the peak overflows
@example(fp=SLOW_TURN, v=0.1, w=3.0)
def test_what_reaches_the_driver_is_finite_within_limits_and_keeps_the_curvature(fp, v, w):
    b = opened(footprint=fp)
    b.set_velocity(v, w, 1.0)
    (sv, sw, t), = b.sent
    assert t == 1.0 and math.isfinite(sv) and math.isfinite(sw)
    assert wheel_peak(fp, sv, sw) <= fp.max_speed * (1 + 1e-12)
    assert abs(sw) <= fp.max_turn_rate * (1 + 1e-12)
    finite = math.isfinite(v) and math.isfinite(w)
    within = finite and wheel_peak(fp, v, w) <= fp.max_speed and abs(w) <= fp.max_turn_rate
    s = b.stats
    assert (s.commands, s.nonfinite_commands, s.clipped_commands) == (1, int(not finite), int(finite and not within))
    if not finite:
        assert (sv, sw) == (0.0, 0.0)
    elif within:
        assert (sv, sw) == (v, w)                                   # passed through untouched
    else:
        k = sw / w if abs(w) * fp.track >= abs(v) else sv / v       # from the larger term: one factor for both
        assert 0 < k < 1
        assert sv == pytest.approx(v * k, rel=1e-12, abs=1e-300) and sw == pytest.approx(w * k, rel=1e-12, abs=1e-300)
        at_limit = (math.isclose(wheel_peak(fp, sv, sw), fp.max_speed, rel_tol=1e-9)
                    or math.isclose(abs(sw), fp.max_turn_rate, rel_tol=1e-9))
        assert at_limit                                             # scaled no further than needed


def test_counters_add_up_over_a_mixed_sequence():
    b = opened()
    for v, w in [(0.1, 0.0), (math.nan, 0.0), (2.0, 0.0), (0.0, math.inf), (0.0, 10.0), (0.2, 0.3)]:
        b.set_velocity(v, w, 0.1)
    b.stop(0.2)
    s = b.stats
    assert (s.commands, s.nonfinite_commands, s.clipped_commands, s.watchdog_stops) == (7, 2, 2, 0)
    assert b.sent[-1] == (0.0, 0.0, 0.2)


def test_a_tighter_turn_rate_limits_turning_alone():
    b = opened(footprint=SLOW_TURN)
    b.set_velocity(0.2, 2.0, 0.0)                        # wheels 0.6 m/s: fine; 2 rad/s: over 1 rad/s
    sv, sw, _ = b.sent[-1]
    assert (sv, sw) == pytest.approx((0.1, 1.0)) and b.stats.clipped_commands == 1


@pytest.mark.parametrize("kw", [
    {"radius": 0.0}, {"track": -0.2}, {"max_speed": math.nan}, {"max_turn_rate": math.inf},
    {"max_turn_rate": 5.0},                               # faster than the wheels can turn it
])
def test_bad_footprints_are_one_line_input_errors(kw):
    args = {"radius": 0.17, "track": 0.235, "max_speed": 0.5, "max_turn_rate": 4.0, **kw}
    with pytest.raises(InputError) as exc:
        Footprint(**args)
    assert "\n" not in str(exc.value) and "expected" in str(exc.value)


# ----------------------------------------------------------------------------- watchdog
def test_watchdog_stops_once_after_the_period_and_logs_once(caplog):
    b = opened(watchdog=0.5)
    b.set_velocity(0.2, 0.0, 1.0)
    with caplog.at_level(logging.WARNING):
        for t in (1.2, 1.499):
            b.poll(t)
        assert len(b.sent) == 1 and b.stats.watchdog_stops == 0
        b.poll(1.5)
        assert b.sent[-1] == (0.0, 0.0, 1.5) and b.stats.watchdog_stops == 1
        for k in range(20):
            b.poll(1.6 + k)
    assert len(b.sent) == 2 and b.stats.watchdog_stops == 1
    assert sum("watchdog" in r.getMessage() for r in caplog.records) == 1
    assert b.stats.commands == 1                          # the watchdog's stop is not a command taken


def test_no_watchdog_after_a_stop_or_while_commands_keep_coming():
    b = opened(watchdog=0.5)
    b.set_velocity(0.0, 0.0, 0.0)
    b.poll(10.0)
    b.set_velocity(0.1, 0.1, 10.0)
    for k in range(1, 30):
        b.poll(10.0 + 0.1 * k)
        b.set_velocity(0.1, 0.1, 10.0 + 0.1 * k)
    assert b.stats.watchdog_stops == 0


def test_a_nonfinite_command_is_a_stop_that_needs_no_watchdog():
    b = opened(watchdog=0.5)
    b.set_velocity(0.3, 0.0, 0.0)
    b.set_velocity(math.nan, 0.0, 0.1)
    b.poll(5.0)
    assert b.stats.watchdog_stops == 0 and b.sent[-1] == (0.0, 0.0, 0.1)


@settings(max_examples=200, deadline=None)
@given(steps=st.lists(st.tuples(st.floats(0.0, 0.4), st.sampled_from(["poll", "move", "stop"])), max_size=40))
def test_watchdog_matches_a_reference_model(steps):
    """The watchdog sends a stop exactly when the base was last told to move and no command came for
    ``watchdog`` seconds, and then not again until it moves anew."""
    b = opened(watchdog=0.5)
    t, last, moving, stops = 0.0, 0.0, False, 0
    for dt, action in steps:
        t += dt
        if action == "poll":
            b.poll(t)
            if moving and t - last >= 0.5:
                moving, stops = False, stops + 1
        else:
            b.set_velocity(0.2 if action == "move" else 0.0, 0.0, t)
            last, moving = t, action == "move"
    assert b.stats.watchdog_stops == stops


# ----------------------------------------------------------------------------- lifecycle
def test_nothing_happens_before_open_and_after_close():
    b = FakeBase()
    assert b.poll(1.0) is False and b.reads == []
    with pytest.raises(RuntimeError, match="before open"):
        b.set_velocity(0.1, 0.0, 1.0)
    assert b.stats.commands == 0
    b.open(2.0)
    b.set_velocity(0.2, 0.0, 2.0)
    b.close()
    b.close()                                             # closing twice closes once
    assert b.closed == 1 and b.poll(9.0) is False and b.stats.watchdog_stops == 0


def test_reopening_closes_first_and_restarts_the_watchdog_clock():
    b = opened()
    b.set_velocity(0.2, 0.0, 0.0)
    b.open(100.0)
    assert (b.opened, b.closed) == (2, 1)
    b.poll(100.4)
    assert b.stats.watchdog_stops == 0                    # a fresh link is not moving


def test_poll_returns_what_the_driver_read():
    b = opened()
    assert b.poll(0.1) is True
    b.fresh = False
    assert b.poll(0.2) is False and b.reads == [0.1, 0.2]


def test_no_fresh_odometry_for_the_input_timeout_holds_the_base_still_one_line_per_episode(caplog):
    b = opened(watchdog=0.5)
    b.input_period = 0.25                          # 3 periods: 0.75 s, more than the watchdog
    assert b.input_timeout == 0.75
    with caplog.at_level(logging.WARNING):
        for k in range(1, 11):                     # fresh odometry every 0.1 s while driving
            b.poll(k * 0.1)
            b.set_velocity(0.2, 0.0, k * 0.1)
        assert b.sent[-1][:2] == (0.2, 0.0) and not b.blind
        b.fresh = False                            # the device babbles or goes silent
        t = 1.0
        while t < 3.0:
            t = round(t + 0.05, 2)
            b.poll(t)
            b.set_velocity(0.2, 0.0, t)
            if t < 1.75:
                assert b.sent[-1][:2] == (0.2, 0.0), t
            else:
                assert b.blind and b.sent[-1][:2] == (0.0, 0.0), t
        b.fresh = True
        b.poll(3.05)
        b.set_velocity(0.2, 0.0, 3.05)
        assert not b.blind and b.sent[-1][:2] == (0.2, 0.0)
    assert b.stats.input_losses == 1 and b.stats.watchdog_stops == 0
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2 and "no valid input" in lines[0] and "again after 2.05 s" in lines[1], lines


def test_no_input_watchdog_before_the_first_odometry():
    b = opened(watchdog=0.5)
    b.fresh = False                                # a base that has not streamed yet (a handshake)
    for k in range(1, 30):
        b.poll(k * 0.1)
        b.set_velocity(0.2, 0.0, k * 0.1)
    assert not b.blind and b.sent[-1][:2] == (0.2, 0.0) and b.stats.input_losses == 0
