"""Range by pybullet ray casts: a set of beams mounted on a body, cast in one rayTestBatch per pass.

A beam set is an (n, 4) array, per ray its origin x, y and direction angle in the body's frame and the number of
the beam (transducer) it belongs to; :func:`fan` builds one for beams of a given width, :func:`cast` measures it
from a body pose.  The Pioneer's sonar cones use it (:mod:`sitl.bodies.pioneer3dx`); a laser's beams can too.
"""
from __future__ import annotations

import math

import numpy as np
import pybullet as p


def fan(mounts, beam: float, rays: int) -> np.ndarray:
    """(len(mounts) * rays, 4) rays spread evenly over ``beam`` (rad) about each mount's heading; ``mounts`` are
    (x, y, heading) in m, m, rad in the body frame, numbered in order."""
    rows = []
    offsets = np.linspace(-beam / 2, beam / 2, rays)
    for num, (x, y, h) in enumerate(mounts):
        for d in offsets:
            rows.append((x, y, h + d, num))
    return np.asarray(rows, dtype=float)


def cast(rays: np.ndarray, pose: tuple[float, float, float], z: float, max_range: float, body_id: int,
         kw: dict) -> tuple[np.ndarray, int]:
    """Distance (m) along each of ``rays`` from a body at ``pose`` (x, y, yaw), at height ``z``, to the nearest
    surface not of ``body_id`` (a ray that hits its own body starts again just past the hit, up to three
    passes); ``max_range`` when nothing is hit.  Also the number of rays cast."""
    x, y, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    ox = x + c * rays[:, 0] - s * rays[:, 1]
    oy = y + s * rays[:, 0] + c * rays[:, 1]
    ang = yaw + rays[:, 2]
    dx, dy = np.cos(ang), np.sin(ang)
    start = np.zeros(len(rays))
    dist = np.full(len(rays), max_range)
    todo = np.arange(len(rays))
    cast_n = 0
    for _ in range(3):                      # a ray that hits this body starts again just past the hit
        if not len(todo):
            break
        frm = np.stack([ox[todo] + dx[todo] * start[todo], oy[todo] + dy[todo] * start[todo],
                        np.full(len(todo), z)], axis=1)
        to = np.stack([ox[todo] + dx[todo] * max_range, oy[todo] + dy[todo] * max_range,
                       np.full(len(todo), z)], axis=1)
        hits = p.rayTestBatch(frm.tolist(), to.tolist(), **kw)
        cast_n += len(todo)
        again = []
        for k, h in zip(todo, hits):
            if h[0] < 0:
                continue
            d = start[k] + h[2] * (max_range - start[k])
            if h[0] == body_id:
                start[k] = d + 1e-3
                again.append(k)
            else:
                dist[k] = d
        todo = np.asarray(again, dtype=int)
    return dist, cast_n
