"""The Pioneer 3-DX sonar ring in closed form, for every robot at once (discs and arena walls: the foraging world).

Each of the 16 transducers (positions and headings from AriaCoda ``params/p3dx-sh.p``, in
:data:`runtime.drivers.arcos_protocol.P3DX_SH`) reports the distance to the nearest surface inside its beam, a
cone of :data:`BEAM` (25 degrees: the Polaroid 600-series transducer's main lobe, as
:mod:`sitl.bodies.pioneer3dx` uses) about its heading, up to :data:`MAX_RANGE` (5 m, ARIA's sonar range
device); beyond it (no echo) it reports :data:`MAX_RANGE`.  The world holds only discs (robots) and the four
arena walls, so the nearest point in a cone has a closed form, and numpy computes every transducer of every
robot against every disc and wall in one pass (no ray casts):

* a disc whose centre lies inside the cone: the near side of the disc along the line to its centre,
  ``L - R``;
* otherwise the nearest point lies on the cone's edge nearer the centre (angle ``off`` past the edge): that
  ray enters the disc at ``L cos(off) - sqrt(R^2 - L^2 sin(off)^2)`` if it meets it at all;
* a wall at perpendicular distance ``p``: ``p`` if the wall's normal lies inside the cone, else
  ``p / cos(off)`` along the edge nearer the normal.

The full-fidelity :class:`sitl.bodies.pioneer3dx.SimPioneer3DX` casts five pybullet rays per transducer
instead; the closed form is exact for discs and walls and sees into the gaps between five rays.
Readings are placed as ARIA places them (``range`` along the transducer's heading) and given to the executive
as ``(bearing, distance)`` from the robot centre, as the ARCOS driver does.
"""
from __future__ import annotations

import math
from itertools import compress

import numpy as np

from runtime.control import compiled
from runtime.drivers.arcos_protocol import P3DX_SH

BEAM = math.radians(25.0)
MAX_RANGE = P3DX_SH.sonar_max_range_mm / 1000.0           # m
MIN_RANGE = 0.15          # m: nearer echoes return while the transducer still rings; it reports none
UNITS = np.array([(u.x / 1000.0, u.y / 1000.0, math.radians(u.heading)) for u in P3DX_SH.sonar_units])
N_SONARS = len(UNITS)
# (bearing, distance from the centre) of a reading r along each transducer's heading: precomputed parts
_UX, _UY, _UH = UNITS[:, 0], UNITS[:, 1], UNITS[:, 2]
_CH, _SH = np.cos(_UH), np.sin(_UH)
_WALL_NORMALS = np.array([0.0, math.pi, math.pi / 2, -math.pi / 2])     # +x, -x, +y, -y walls


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + math.pi) % (2 * math.pi) - math.pi


def transducers(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World x, y and heading of every transducer: three (N, 16) arrays for ``poses`` (N, 3)."""
    x, y, yaw = poses[:, 0:1], poses[:, 1:2], poses[:, 2:3]
    c, s = np.cos(yaw), np.sin(yaw)
    return x + c * _UX - s * _UY, y + s * _UX + c * _UY, yaw + _UH


def ring_ranges(poses: np.ndarray, radius: float, half_size: float, beam: float = BEAM,
                max_range: float = MAX_RANGE, min_range: float = MIN_RANGE) -> np.ndarray:
    """(N, 16) ranges (m, from each transducer) of robots at ``poses`` (N, 3), each a disc of ``radius``, in a
    square arena of walls at +-``half_size``; ``max_range`` where nothing echoes between ``min_range`` and
    ``max_range``."""
    n = len(poses)
    half = beam / 2
    ox, oy, h = transducers(poses)
    if compiled.ENABLED:            # numpy's arctan2 is its own (vectorised, not the C library's): it stays here
        bearing = np.arctan2(poses[None, None, :, 1] - oy[..., None], poses[None, None, :, 0] - ox[..., None])
        return _ring_kernel(np.ascontiguousarray(poses, dtype=float), ox, oy, h, bearing, float(radius),
                            float(half_size), half, float(max_range), float(min_range), _WALL_NORMALS)
    # walls: perpendicular distance and the angle from the beam to the wall's normal
    p = np.stack([half_size - ox, half_size + ox, half_size - oy, half_size + oy], axis=-1)      # (N, 16, 4)
    off = np.maximum(np.abs(_wrap(_WALL_NORMALS - h[..., None])) - half, 0.0)
    cos_off = np.cos(off)
    best = np.min(np.where(cos_off > 1e-9, np.maximum(p, 0.0) / np.maximum(cos_off, 1e-9), np.inf), axis=-1)
    if n > 1:
        qx = poses[None, None, :, 0] - ox[..., None]                     # (N, 16, N): to every robot centre
        qy = poses[None, None, :, 1] - oy[..., None]
        dist = np.hypot(qx, qy)
        off = np.maximum(np.abs(_wrap(np.arctan2(qy, qx) - h[..., None])) - half, 0.0)
        perp = dist * np.sin(off)
        along = dist * np.cos(off)
        enter = along - np.sqrt(np.maximum(radius * radius - perp * perp, 0.0))
        hit = (perp <= radius) & (along > 0) & (off < math.pi / 2)
        r = np.where(off == 0.0, dist - radius, enter)
        r = np.where(hit, np.maximum(r, 0.0), np.inf)
        r[np.arange(n), :, np.arange(n)] = np.inf                       # a robot's own body
        best = np.minimum(best, r.min(axis=-1))
    return np.where(best < min_range, max_range, np.minimum(best, max_range))


@compiled.kernel
def _ring_kernel(poses, ox, oy, h, bearing, radius, half_size, half, max_range, min_range, normals):
    """:func:`ring_ranges` from the transducers' poses and the bearings to every robot (numpy's), transducer by
    transducer: the same floating-point operations in the same order (numpy's ``np.maximum(a, b)`` is ``a if a >= b
    else b``, ``%`` is Python's, ``hypot`` the C library's), so the same bits (tests/test_control_compiled.py)."""
    n, m = ox.shape
    out = np.empty((n, m))
    two_pi, quarter = 2 * math.pi, math.pi / 2
    for i in range(n):
        for j in range(m):
            x, y, hj = ox[i, j], oy[i, j], h[i, j]
            best = np.inf
            for w in range(4):
                p = half_size - x if w == 0 else half_size + x if w == 1 else half_size - y if w == 2 \
                    else half_size + y
                off = abs((normals[w] - hj + math.pi) % two_pi - math.pi) - half
                off = off if off >= 0.0 else 0.0
                cos_off = math.cos(off)
                if cos_off > 1e-9:
                    v = (p if p >= 0.0 else 0.0) / (cos_off if cos_off >= 1e-9 else 1e-9)
                    best = v if v <= best else best
            for k in range(n):
                if k == i:
                    continue                                       # a robot's own body
                dist = np.hypot(poses[k, 0] - x, poses[k, 1] - y)
                off = abs((bearing[i, j, k] - hj + math.pi) % two_pi - math.pi) - half
                off = off if off >= 0.0 else 0.0
                perp = dist * math.sin(off)
                along = dist * math.cos(off)
                if perp <= radius and along > 0 and off < quarter:
                    inside = radius * radius - perp * perp
                    r = dist - radius if off == 0.0 else along - math.sqrt(inside if inside >= 0.0 else 0.0)
                    r = r if r >= 0.0 else 0.0
                    best = r if r <= best else best
            out[i, j] = max_range if best < min_range else (best if best <= max_range else max_range)
    return out


def readings(ranges: np.ndarray, max_range: float = MAX_RANGE) -> tuple[tuple[float, float], ...]:
    """One robot's 16 ranges as the executive takes them: ``(bearing, distance)`` from the robot centre of each
    reading that echoed (below ``max_range``), placed ``range`` along its transducer's heading."""
    keep = ranges < max_range
    px = _UX[keep] + ranges[keep] * _CH[keep]
    py = _UY[keep] + ranges[keep] * _SH[keep]
    return tuple(zip(np.arctan2(py, px).tolist(), np.hypot(px, py).tolist()))


def readings_all(ranges: np.ndarray, max_range: float = MAX_RANGE) -> list[tuple[tuple[float, float], ...]]:
    """:func:`readings` of every row of ``ranges`` (N, 16), in one pass over all robots (the same operations on
    each reading: the same values)."""
    px = _UX + ranges * _CH
    py = _UY + ranges * _SH
    bearing, dist = np.arctan2(py, px).tolist(), np.hypot(px, py).tolist()
    keep = (ranges < max_range).tolist()
    return [tuple(compress(zip(bs, ds), ks)) for bs, ds, ks in zip(bearing, dist, keep)]
