"""Range by pybullet ray casts: beam sets mounted on bodies, every body's rays in one ``rayTestBatch`` per pass.

A beam set is an (n, 4) array, per ray its origin x, y and direction angle in the frame it is given in and the
number of the beam (transducer, laser step) it belongs to.  :func:`fan` builds sonar-like cones of a few rays each,
:func:`laser` a scanner's single-ray steps, :func:`mounted` moves a set from a sensor's own frame to the body's by
the sensor's mounted pose.  :class:`Beams` is such a set carried by a body at a height with a range limit; any body
with ``body_id``, ``pose()`` and ``_kw`` (:class:`sitl.bodies.diffdrive.GroundTruth`) can carry any number.

:func:`cast_many` measures several sets, on several bodies of one world, at once: the rays of all of them go into
one ``rayTestBatch`` per pass (a ray that hits its own body starts again just past the hit, up to three passes),
so a fleet's laser scans and sonar rings cost one call into pybullet, not one per robot.  Each ray's arithmetic is
the same whatever else is in the batch: a set cast alone or with others gives bit-identical distances.  The
Pioneer's sonar cones (:mod:`sitl.bodies.pioneer3dx`) and the RPLIDAR emulator's beams
(:mod:`sitl.devices.rplidar`) use it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pybullet as p

PASSES = 3                   # a ray that keeps hitting its own body is given up (reads max_range) after these
MAX_BATCH = 16384            # rays per rayTestBatch call (pybullet's MAX_RAY_INTERSECTION_BATCH_SIZE)


def fan(mounts, beam: float, rays: int) -> np.ndarray:
    """(len(mounts) * rays, 4) rays spread evenly over ``beam`` (rad) about each mount's heading; ``mounts`` are
    (x, y, heading) in m, m, rad in the body frame, numbered in order."""
    rows = []
    offsets = np.linspace(-beam / 2, beam / 2, rays)
    for num, (x, y, h) in enumerate(mounts):
        for d in offsets:
            rows.append((x, y, h + d, num))
    return np.asarray(rows, dtype=float)


def laser(angles: np.ndarray) -> np.ndarray:
    """(n, 4) one ray per step from the sensor's origin along each of ``angles`` (rad, counter-clockwise), step
    k numbered k."""
    a = np.asarray(angles, dtype=float)
    return np.stack([np.zeros(len(a)), np.zeros(len(a)), a, np.arange(len(a), dtype=float)], axis=1)


def mounted(rays: np.ndarray, mount: tuple[float, float, float]) -> np.ndarray:
    """``rays`` given in a sensor's frame, moved to the body's frame for a sensor at ``mount`` = (x, y, yaw)."""
    x, y, yaw = mount
    if (x, y, yaw) == (0.0, 0.0, 0.0):
        return rays
    c, s = math.cos(yaw), math.sin(yaw)
    out = rays.copy()
    out[:, 0] = x + c * rays[:, 0] - s * rays[:, 1]
    out[:, 1] = y + s * rays[:, 0] + c * rays[:, 1]
    out[:, 2] = rays[:, 2] + yaw
    return out


@dataclass(frozen=True)
class Beams:
    """A beam set (in the body's frame) a body carries at height ``z`` (m above the floor), reading ``max_range``
    (m) where nothing is hit."""
    body: object
    rays: np.ndarray
    z: float
    max_range: float

    def select(self, numbers) -> "Beams":
        """The rays of the beams numbered in ``numbers`` only."""
        sel = np.isin(self.rays[:, 3], np.asarray(list(numbers), dtype=float))
        return Beams(self.body, self.rays[sel], self.z, self.max_range)

    def along(self, angles: np.ndarray) -> "Beams":
        """Rays from the set's first ray's origin along ``angles`` (body frame): a spinning scanner's next steps."""
        rays = np.empty((len(angles), 4))
        rays[:, 0], rays[:, 1] = self.rays[0, 0], self.rays[0, 1]
        rays[:, 2] = angles
        rays[:, 3] = np.arange(len(angles))
        return Beams(self.body, rays, self.z, self.max_range)


def _origins(rays: np.ndarray, pose: tuple[float, float, float]):
    x, y, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    ox = x + c * rays[:, 0] - s * rays[:, 1]
    oy = y + s * rays[:, 0] + c * rays[:, 1]
    ang = yaw + rays[:, 2]
    return ox, oy, np.cos(ang), np.sin(ang)


def cast_many(sets: list[Beams], poses: list | None = None, kw: dict | None = None) -> tuple[list[np.ndarray], int]:
    """Distance (m) along each ray of each of ``sets`` to the nearest surface not of its own body; the set's
    ``max_range`` where nothing is hit.  ``poses`` (x, y, yaw per set; default each body's ``pose()``) and ``kw``
    (the pybullet client; default the first body's) may be given.  Also the number of rays cast."""
    if not sets:
        return [], 0
    kw = sets[0].body._kw if kw is None else kw
    poses = [b.body.pose() for b in sets] if poses is None else poses
    parts = [_origins(b.rays, pose) for b, pose in zip(sets, poses)]
    ox = np.concatenate([q[0] for q in parts])
    oy = np.concatenate([q[1] for q in parts])
    dx = np.concatenate([q[2] for q in parts])
    dy = np.concatenate([q[3] for q in parts])
    zs = np.concatenate([np.full(len(b.rays), float(b.z)) for b in sets])
    reach = np.concatenate([np.full(len(b.rays), float(b.max_range)) for b in sets])
    own = np.concatenate([np.full(len(b.rays), b.body.body_id, dtype=np.int64) for b in sets])
    total = len(ox)
    start = np.zeros(total)
    dist = reach.copy()
    todo = np.arange(total)
    cast_n = 0
    for _ in range(PASSES):
        if not len(todo):
            break
        frm = np.stack([ox[todo] + dx[todo] * start[todo], oy[todo] + dy[todo] * start[todo], zs[todo]], axis=1)
        to = np.stack([ox[todo] + dx[todo] * reach[todo], oy[todo] + dy[todo] * reach[todo], zs[todo]], axis=1)
        hits = []
        for lo in range(0, len(todo), MAX_BATCH):
            hits += p.rayTestBatch(frm[lo:lo + MAX_BATCH].tolist(), to[lo:lo + MAX_BATCH].tolist(), **kw)
        cast_n += len(todo)
        hit_id = np.array([h[0] for h in hits], dtype=np.int64)
        frac = np.array([h[2] for h in hits], dtype=float)
        hit = hit_id >= 0
        k = todo[hit]
        d = start[k] + frac[hit] * (reach[k] - start[k])
        mine = hit_id[hit] == own[k]
        dist[k[~mine]] = d[~mine]
        start[k[mine]] = d[mine] + 1e-3          # hit its own body: start again just past the hit
        todo = k[mine]
    out, lo = [], 0
    for b in sets:
        out.append(dist[lo:lo + len(b.rays)])
        lo += len(b.rays)
    return out, cast_n

