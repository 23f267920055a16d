"""The one interface every mobile base driver implements, and the policy all of them share.

A driver owns one link (serial via ``serial.serial_for_url`` or a CAN bus), speaks the base's real
protocol, and turns it into odometry and a few sensor flags.  It is polled, never threaded: the
daemon calls :meth:`MobileBase.poll` every control cycle with the current time; ``poll`` reads
whatever bytes are waiting (non-blocking), decodes them, and enforces the command watchdog.

:class:`MobileBase` holds what is the same for every base (as python-can's ``BusABC`` does for
buses): the finite-value check, clipping to the base's :class:`Footprint` with the curvature kept,
the command watchdog, the lifecycle state and the policy counters in :class:`LinkStats`.  A driver
subclasses it, calls ``super().__init__(footprint, watchdog, log)`` and implements four hooks:

* ``_open(now)``: open the link, wake the base, start its sensor stream (raise ``InputError`` if the
  link cannot be opened);
* ``_close()``: stop the motors, stop streaming, close the link;
* ``_read(now) -> bool``: decode what has arrived into :attr:`odometry` / :attr:`sensors`; True if
  the odometry is new;
* ``_command(v, w, now) -> bool``: send a velocity that is already finite and within the footprint;
  True if the base was told to move (False when the command is a stop, including one that rounds to
  zero on every actuator), so the watchdog knows whether there is anything to stop.
"""
from __future__ import annotations

import abc
import math
from dataclasses import dataclass, field

from runtime.errors import InputError


class DeviceLost(RuntimeError):
    """The base's link is gone (the serial device vanished, the bus went down): nothing can be sent or read any
    more.  ``str()`` is one line; the daemon stops on it."""


LOST_AFTER = 20             # consecutive failed reads (one per poll) before a driver reports its device lost


@dataclass(frozen=True)
class Footprint:
    """A differential-drive base's size and limits, in metres, m/s and rad/s.

    ``radius``: the circle about the base's centre (the point odometry and the pose refer to) that
    holds the whole body; planning inflates obstacles by it and avoidance keeps it clear.
    ``track``: the distance between the wheels' contact points.  ``max_speed``: the fastest either
    wheel is driven (the limit the driver enforces, at most what the hardware does).
    ``max_turn_rate``: the fastest turn in place the driver commands; at most ``2 * max_speed / track``
    (a tighter value limits turning on its own, keeping the curvature).
    """
    radius: float
    track: float
    max_speed: float
    max_turn_rate: float

    def __post_init__(self):
        for name in ("radius", "track", "max_speed", "max_turn_rate"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise InputError(f"base footprint {name}: expected a finite number > 0, got {value!r}")
        if self.max_turn_rate > self.wheel_turn_rate * (1 + 1e-9):
            raise InputError(f"base footprint max_turn_rate {self.max_turn_rate!r}: expected at most "
                             f"2 * max_speed / track = {self.wheel_turn_rate:.4g} rad/s")

    @property
    def wheel_turn_rate(self) -> float:
        """The turn rate in place with both wheels at ``max_speed`` (rad/s)."""
        return 2.0 * self.max_speed / self.track

    def scale(self, v: float, w: float) -> float:
        """The factor in (0, 1] that brings finite ``(v, w)`` within the limits; both are scaled by it,
        so both wheels are scaled alike and the curvature ``w / v`` is kept."""
        k = 1.0
        half = self.track / 2.0
        peak = abs(v) + abs(w) * half                        # the faster wheel's speed
        if peak > self.max_speed:
            if math.isfinite(peak):
                k = self.max_speed / peak
            else:                                            # finite v, w near 1e308: peak overflowed
                s = max(abs(v), abs(w))
                k = (self.max_speed / s) / (abs(v) / s + abs(w) / s * half)
        if self.max_turn_rate < self.wheel_turn_rate and abs(w) * k > self.max_turn_rate:
            k = self.max_turn_rate / abs(w)
        return k


@dataclass
class Odometry:
    """Dead-reckoned pose in the base's own frame (starts at 0, 0, 0) and body velocities."""
    t: float = 0.0
    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0
    v: float = 0.0       # m/s forward
    w: float = 0.0       # rad/s counter-clockwise
    distance: float = 0.0   # total path length (m)

    def advance(self, ds: float, dth: float) -> None:
        """Dead-reckon ``ds`` metres along the mean heading of a turn by ``dth`` radians (midpoint rule)."""
        mid = self.theta + dth / 2.0
        self.x += ds * math.cos(mid)
        self.y += ds * math.sin(mid)
        self.theta = math.remainder(self.theta + dth, math.tau)
        self.distance += abs(ds)


@dataclass
class BaseSensors:
    """What the base senses besides odometry; fields a base does not have keep their defaults.

    ``ranges``: distance readings as ``(bearing, distance)`` pairs, bearing in radians in the robot
    frame (0 ahead, positive to the left, counter-clockwise), distance in metres from the robot's
    centre (not from the sensor), one pair per reading of the latest scan; empty on a base without
    range sensors (a Create).  ``faults``: short names of the faults the base reports now (e.g.
    ``"left_motor_overcurrent"``), empty when it is healthy or reports none.
    """
    bump_left: bool = False
    bump_right: bool = False
    wheel_drop: bool = False
    battery_charge: float = float("nan")     # Ah (or the base's own unit)
    battery_capacity: float = float("nan")
    voltage: float = float("nan")            # V
    current: float = float("nan")            # A (negative = discharging)
    mode: str = "unknown"
    ranges: tuple[tuple[float, float], ...] = ()
    faults: tuple[str, ...] = ()


@dataclass
class LinkStats:
    """Counters of one base: the policy's (kept by :class:`MobileBase`) and the link's (by the driver)."""
    commands: int = 0            # velocity commands taken by set_velocity (stops included)
    nonfinite_commands: int = 0  # of them with a nan/inf, sent as a stop
    clipped_commands: int = 0    # of them scaled down to the footprint's limits
    watchdog_stops: int = 0      # times the watchdog stopped a base left moving without commands
    input_losses: int = 0        # episodes of no valid input (odometry) for a watchdog period while told to move
    frames: int = 0              # good frames decoded
    bad_checksum: int = 0        # frames dropped for a checksum mismatch
    dropped_bytes: int = 0       # bytes skipped while resynchronising
    extra: dict = field(default_factory=dict)    # the driver's own counters


class MobileBase(abc.ABC):
    """Differential-drive base.  All methods are non-blocking and take the current time ``now`` (s)."""

    odometry: Odometry
    sensors: BaseSensors
    stats: LinkStats
    input_period = 0.0         # s between the odometry updates the base sends (the input watchdog waits 3 at least)
    latches_faults = False     # True: ``sensors.faults`` stay, and the base stands, until reset_faults() clears them
    ranging = False            # True: it has range sensors (``sensors.ranges`` empty then means nothing in range)

    @property
    def sensor_kinds(self) -> tuple[str, ...]:
        """The sensors that are part of the base, as the allocation names them (the Pioneer's ring: "sonar")."""
        return ()

    def __init__(self, footprint: Footprint, watchdog: float, log):
        if not (isinstance(watchdog, (int, float)) and math.isfinite(watchdog) and watchdog > 0):
            raise InputError(f"{type(self).__name__} watchdog {watchdog!r}: expected seconds > 0")
        self._footprint = footprint
        self.watchdog = float(watchdog)
        self.log = log
        self.odometry = Odometry()
        self.sensors = BaseSensors()
        self.stats = LinkStats()
        self.is_open = False
        self._last_cmd_t: float | None = None
        self._moving = False               # the last command sent told the base to move
        self._valid_t: float | None = None     # the last poll that decoded fresh odometry since open
        self.blind = False                     # the last poll found no valid input for input_timeout: held still
        self._blind_since: float | None = None  # an input-loss episode was logged at this time
        self._failures: dict[str, int] = {}    # link failures in a row, by counter (_link_failed)

    @property
    def footprint(self) -> Footprint:
        """Size and limits of this base (radius for obstacle inflation and avoidance)."""
        return self._footprint

    # ------------------------------------------------------------------ lifecycle
    def open(self, now: float) -> None:
        """Open the link, wake the base, start its sensor stream; the watchdog counts from ``now``."""
        if self.is_open:
            self.close()
        self._open(now)
        self.is_open = True
        self._last_cmd_t = now
        self._valid_t = None
        self._blind_since = None
        self.blind = False
        self._moving = False

    def close(self) -> None:
        """Stop the motors, stop streaming, close the link.  Closing a closed base does nothing."""
        if not self.is_open:
            return
        self.is_open = False
        self._moving = False
        self._close()

    # ------------------------------------------------------------------ cycle
    def poll(self, now: float) -> bool:
        """Read and decode what has arrived, then enforce both watchdogs: no command for ``watchdog`` s, and no
        valid input (fresh odometry) for ``input_timeout`` s once there was some since open, which holds the base still
        until valid input returns (a base that babbles or goes silent is not driven blind).  True if new
        odometry."""
        if not self.is_open:
            return False
        fresh = self._read(now)
        if fresh:
            if self._blind_since is not None:
                self.log.warning("valid input from the base again after %.2f s: driving again",
                                 now - self._blind_since)
                self._blind_since = None
            self._valid_t = now
        if self._moving and now - self._last_cmd_t >= self.watchdog:
            self._moving = self._command(0.0, 0.0, now)
            self.stats.watchdog_stops += 1
            self.log.warning("watchdog: no command for %.2f s, base stopped", now - self._last_cmd_t)
        self.blind = self._valid_t is not None and now - self._valid_t >= self.input_timeout
        if self._moving and self.blind:
            self._moving = self._command(0.0, 0.0, now)
            self._lost_input(now)
        return fresh

    @property
    def input_timeout(self) -> float:
        """Seconds without fresh odometry before the base is held still: ``watchdog``, at least 3 input periods."""
        return max(self.watchdog, 3 * self.input_period)

    def _lost_input(self, now: float) -> None:
        """One line per episode, when it first stops (or refuses to move) the base."""
        if self._blind_since is None:
            self._blind_since = self._valid_t
            self.stats.input_losses += 1
            s = self.stats
            self.log.warning("no valid input from the base for %.2f s (%d bytes dropped, %d bad checksums so far): "
                             "base held still until it returns", now - self._valid_t, s.dropped_bytes,
                             s.bad_checksum)

    def set_velocity(self, v: float, w: float, now: float) -> None:
        """Command forward speed ``v`` (m/s) and turn rate ``w`` (rad/s).  A nan or inf stops the base;
        a command beyond the footprint's limits is scaled down, both wheels alike."""
        if not self.is_open:
            raise RuntimeError(f"{type(self).__name__}.set_velocity before open()")
        nonfinite = not (math.isfinite(v) and math.isfinite(w))
        k = 1.0
        if nonfinite:
            self.log.warning("non-finite velocity command (%r, %r): stopping", v, w)
            v = w = 0.0
        else:
            k = self._footprint.scale(v, w)
            if k < 1.0:
                v, w = v * k, w * k
        if (v, w) != (0.0, 0.0) and self.blind:
            self._lost_input(now)
            v = w = 0.0
        self._moving = self._command(v, w, now)
        self._last_cmd_t = now
        self.stats.commands += 1
        self.stats.nonfinite_commands += nonfinite
        self.stats.clipped_commands += k < 1.0

    def stop(self, now: float) -> None:
        self.set_velocity(0.0, 0.0, now)

    def _link_failed(self, counter: str, exc: Exception, what: str) -> None:
        """A read or write on the link failed: count it in ``stats.extra[counter]``; LOST_AFTER of one counter in
        a row (no :meth:`_link_ok` between) raise :class:`DeviceLost` naming ``what``; the 1st, 10th, 100th and
        every 1000th failure is logged."""
        n = self.stats.extra[counter] = self.stats.extra.get(counter, 0) + 1
        run = self._failures[counter] = self._failures.get(counter, 0) + 1
        if run >= LOST_AFTER:
            raise DeviceLost(f"{what}: {run} in a row failed ({exc})")
        if n in (1, 10, 100) or n % 1000 == 0:
            self.log.warning("%s: %s", what, exc)

    def _link_ok(self, counter: str) -> None:
        self._failures[counter] = 0

    # ------------------------------------------------------------------ stopping from outside the daemon
    guard: float | None = None   # s of daemon silence before its stop guard stops the base; None: no guard

    def stop_bytes(self) -> tuple[bytes, bytes] | None:
        """What stops the base when written on its port by someone else than this driver (the stop guard,
        ``mrta stop-base``): ``(pause, final)``, the stop for a frozen daemon that may wake up and the one for a
        dead daemon; None for a base that cannot be stopped that way (it stops by its own watchdog).  A base that
        has them has a :class:`~runtime.drivers.serial_link.SerialLink` as ``link`` (``mrta stop-base`` opens it)."""
        return None

    def port_fd(self) -> int | None:
        """The open port's file descriptor, for the stop guard; None when it has none."""
        return None

    def reset_faults(self, now: float) -> bool:
        """Ask the base to clear the faults it reports in ``sensors.faults`` and drive again (the operator's
        request; it may take a few polls).  True if a reset was started; a base without resettable faults
        returns False."""
        return False

    # ------------------------------------------------------------------ driver hooks
    @abc.abstractmethod
    def _open(self, now: float) -> None:
        """Open the link, wake the base, start its sensor stream."""

    @abc.abstractmethod
    def _close(self) -> None:
        """Stop the motors, stop streaming, close the link."""

    @abc.abstractmethod
    def _read(self, now: float) -> bool:
        """Decode what has arrived into odometry and sensors.  True if new odometry."""

    @abc.abstractmethod
    def _command(self, v: float, w: float, now: float) -> bool:
        """Send finite, in-limit ``(v, w)``.  True if the base was told to move."""
