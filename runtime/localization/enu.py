"""Geodetic <-> local ENU around a :class:`runtime.config.Datum` (WGS-84, pymap3d).

The fleet frame is ENU at the datum: x east, y north, z up, metres.  Heights are ellipsoidal.
Inputs may be floats or numpy arrays (pymap3d broadcasts).
"""
from __future__ import annotations

import math

import pymap3d

from runtime.config import Datum


def geodetic_to_enu(lat: float, lon: float, alt: float | None, datum: Datum) -> tuple[float, float, float]:
    """(lat, lon in degrees, ellipsoidal height m) -> (east, north, up) metres from the datum.

    A scalar ``alt`` that is None or nan (a fix from RMC alone) is taken as the datum height: east and
    north then stay exact to within (height error) x (distance / earth radius)."""
    if alt is None or (isinstance(alt, float) and not math.isfinite(alt)):
        alt = datum.alt
    return pymap3d.geodetic2enu(lat, lon, alt, datum.lat, datum.lon, datum.alt)


def enu_to_geodetic(e: float, n: float, u: float, datum: Datum) -> tuple[float, float, float]:
    """(east, north, up) metres from the datum -> (lat, lon in degrees, ellipsoidal height m)."""
    return pymap3d.enu2geodetic(e, n, u, datum.lat, datum.lon, datum.alt)


def course_to_yaw(course: float) -> float:
    """Course over ground (rad, clockwise from true north) -> ENU yaw (rad, counter-clockwise from
    east), wrapped to (-pi, pi]."""
    return wrap_angle(math.pi / 2 - course)


def yaw_to_course(yaw: float) -> float:
    """ENU yaw (rad) -> course over ground (rad, clockwise from true north) in [0, 2 pi)."""
    return (math.pi / 2 - yaw) % (2 * math.pi)


def wrap_angle(a: float) -> float:
    """Wrap an angle to (-pi, pi]."""
    a = math.remainder(a, 2 * math.pi)    # [-pi, pi]
    return math.pi if a == -math.pi else a
