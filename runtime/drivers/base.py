"""The one interface every mobile base driver implements.

A driver owns one link (serial via ``serial.serial_for_url`` or a CAN bus), speaks the base's real
protocol, and turns it into odometry and a few sensor flags.  It is polled, never threaded: the
daemon calls :meth:`poll` every control cycle with the current time; ``poll`` reads whatever bytes
are waiting (non-blocking), decodes them, and enforces the command watchdog.
"""
from __future__ import annotations

import abc
from dataclasses import dataclass, field


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


@dataclass
class BaseSensors:
    bump_left: bool = False
    bump_right: bool = False
    wheel_drop: bool = False
    battery_charge: float = float("nan")     # Ah (or the base's own unit)
    battery_capacity: float = float("nan")
    voltage: float = float("nan")            # V
    current: float = float("nan")            # A (negative = discharging)
    mode: str = "unknown"


@dataclass
class LinkStats:
    frames: int = 0            # good frames decoded
    bad_checksum: int = 0      # frames dropped for a checksum mismatch
    dropped_bytes: int = 0     # bytes skipped while resynchronising
    commands: int = 0          # commands written
    watchdog_stops: int = 0    # times the watchdog sent zero velocity
    extra: dict = field(default_factory=dict)


class MobileBase(abc.ABC):
    """Differential-drive base.  All methods are non-blocking."""

    odometry: Odometry
    sensors: BaseSensors
    stats: LinkStats

    @abc.abstractmethod
    def open(self, now: float) -> None:
        """Open the link, wake the base, start its sensor stream."""

    @abc.abstractmethod
    def close(self) -> None:
        """Stop the motors, stop streaming, close the link."""

    @abc.abstractmethod
    def poll(self, now: float) -> bool:
        """Read and decode what has arrived; enforce the watchdog.  True if new odometry."""

    @abc.abstractmethod
    def set_velocity(self, v: float, w: float, now: float) -> None:
        """Command forward speed ``v`` (m/s) and turn rate ``w`` (rad/s); clipped to the base."""

    def stop(self, now: float) -> None:
        self.set_velocity(0.0, 0.0, now)
