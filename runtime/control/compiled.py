"""Compiled kernels for the executive's hottest loops, when numba is installed (the ``fast`` extra).

Each kernel does, element by element, the same floating-point operations in the same order as the numpy code it
stands in for (:mod:`runtime.control.behaviours`, :mod:`runtime.control.arbiter`,
:mod:`runtime.control.pure_pursuit`, and the SITL's sonar ring, which registers its kernel with :func:`kernel`),
so the results are the same bit for bit; what numpy would hand to BLAS (a matrix product, which may fuse
multiplies and adds) or to its own vectorised transcendental functions (``exp``, ``arctan2``) stays in numpy and is
passed in.  The callers take the kernels while
:data:`ENABLED` is True, and their numpy code otherwise: ``tests/test_control_compiled.py`` holds the two paths to
the same bits.

:data:`ENABLED` is off until a host that steps many robots faster than real time in one process turns it on with
:func:`enable` (the in-process host, ``runtime.inprocess.Fleet``, and the lock-step SITL, ``sitl.launcher``): there
the kernels halve the executive's CPU.  A daemon on a robot (or a daemon process of a SITL run) keeps the numpy
code: its 10-20 Hz cycle has time to spare, and the first kernel call would stall it for the import (0.6 s) or,
on a new machine, the compile (about 2 s here, more on a robot's CPU).  Without numba, or with
``MRTA_NO_NUMBA=1`` in the environment, :func:`enable` leaves it off.

numba is imported at the first kernel call; the kernels are compiled then and cached on disk (``cache=True``:
numba's ``__pycache__`` beside this file), so the compile (about 2 s) is paid once per machine, later processes
only the import and load (about 0.6 s).
"""
from __future__ import annotations

import contextlib
import importlib.util
import math
import os
import sys

import numpy as np

AVAILABLE = not os.environ.get("MRTA_NO_NUMBA") and importlib.util.find_spec("numba") is not None
ENABLED = False
_KERNELS: list = []


def enable() -> bool:
    """Turn the kernels on where numba is available (see the module's docstring); True if they are on."""
    global ENABLED
    ENABLED = AVAILABLE
    return ENABLED


@contextlib.contextmanager
def numpy_code():
    """The callers' numpy code inside the block, whatever a host enables there (the benchmarks and tests that set
    the two paths side by side)."""
    global AVAILABLE, ENABLED
    saved = AVAILABLE, ENABLED
    AVAILABLE = ENABLED = False
    try:
        yield
    finally:
        AVAILABLE, ENABLED = saved


def kernel(fn):
    """``fn`` as a kernel: its module's name for it becomes the compiled function.  numba is imported and every
    kernel not yet compiled is wrapped only at the first call of one (a process that never runs the executive, or
    runs it without numba, does not pay for the import: about 0.3 s).  Kernels of other modules (the SITL's sonar
    ring) use it too; callers look a kernel up in its module at each call."""
    if not AVAILABLE:
        return fn
    _KERNELS.append(fn)

    def first_call(*args):
        _compile_all()
        return vars(sys.modules[fn.__module__])[fn.__name__](*args)
    first_call.__name__, first_call.__doc__ = fn.__name__, fn.__doc__
    return first_call


def _compile_all() -> None:
    from numba import njit
    while _KERNELS:             # all at once: a kernel that calls another resolves it from its module's globals
        fn = _KERNELS.pop(0)
        vars(sys.modules[fn.__module__])[fn.__name__] = njit(cache=True, nogil=True, error_model="numpy")(fn)


@kernel
def near_points(pts, reach, c2):
    """The range points within ``reach`` of the robot (``|p|^2 <= reach^2``) and, per point, ``min(c2 - |p|^2,
    -1e-12)``: the start of :meth:`runtime.control.behaviours.AvoidObstacles.time_to_collision`."""
    n = pts.shape[0]
    keep = np.empty((n, 2))
    lim = np.empty(n)
    r2 = reach * reach
    k = 0
    for j in range(n):
        x, y = pts[j, 0], pts[j, 1]
        d2 = x * x + y * y
        if d2 <= r2:
            keep[k, 0], keep[k, 1] = x, y
            m = c2 - d2
            lim[k] = m if m < -1e-12 else -1e-12
            k += 1
    return keep[:k], lim[:k]


@kernel
def first_hits(a, lim, g, speeds, first, nw, steps):
    """Per arc (speed-major), the time of the first sampled step that hits a range point, ``first[0]`` (inf) for
    none: :meth:`runtime.control.behaviours.AvoidObstacles.time_to_collision` from its product ``a`` (rows x
    points: each (turn rate, step) row's ray dotted with each point) on.  A row and point hold the speeds ``v``
    with ``(v g - a)^2 <= a^2 + lim``: ``m = a a + lim``; where ``m >= 0`` the speeds in
    ``[(a - sqrt m) / g, (a + sqrt m) / g]`` (searchsorted left and right) are hit from that step on."""
    nv = speeds.shape[0]
    n = a.shape[1]
    out = np.full(nv * nw, first[0])
    hit = np.zeros(nv, dtype=np.bool_)
    vmin, vmax = speeds[0], speeds[nv - 1]
    for i in range(nw):
        hit[:] = False
        nhit = 0
        for t in range(steps):
            if nhit == nv:                  # every speed of this turn rate hit already: later steps change nothing
                break
            r = i * steps + t
            gr = g[r]
            for q in range(n):
                ar = a[r, q]
                m = ar * ar + lim[q]
                if not m >= 0:
                    continue
                root = math.sqrt(m)
                x0 = (ar - root) / gr
                if x0 > vmax:
                    continue
                x1 = (ar + root) / gr
                if x1 < vmin:
                    continue
                lo, hi = 0, nv              # searchsorted(x0, "left"): the first speed >= x0
                while lo < hi:
                    mid = (lo + hi) >> 1
                    if speeds[mid] < x0:
                        lo = mid + 1
                    else:
                        hi = mid
                s = lo
                while s < nv and speeds[s] <= x1:
                    if not hit[s]:
                        hit[s] = True
                        nhit += 1
                        out[s * nw + i] = first[steps - t]
                    s += 1
    return out


@kernel
def lane_gap(pts, clearance, before):
    """``min(x) - clearance`` over the points ahead (``x > 0``) within the clearance of the heading line
    (``|y| < clearance``) and short of ``before``; inf for none (``AvoidObstacles._lane_gap_of``)."""
    best = np.inf                       # (a NaN x is never ahead: x > 0 fails)
    for j in range(pts.shape[0]):
        x = pts[j, 0]
        if x > 0 and abs(pts[j, 1]) < clearance and x < before and x < best:
            best = x
    return best - clearance


@kernel
def _clip01(t):
    """``np.minimum(np.maximum(t, 0.0), 1.0)`` of one value (a tie gives the second; NaN stays)."""
    t = 0.0 if t <= 0.0 else t
    return 1.0 if t >= 1.0 else t


@kernel
def project(a, d, len2_div, seg_len, len_div, start, end, x, y, fresh, lo, hi, look2, progress):
    """:meth:`runtime.control.pure_pursuit.PurePursuit._project` of a path of two or more points (its per-segment
    constants ``a`` .. ``end``), the robot at (``x``, ``y``): the arc length of the closest point, over the whole
    path when ``fresh``, else within the window [``lo``, ``hi``] of progress if one lies within the look-ahead
    (``look2`` its square), else anywhere from ``lo`` on (``progress`` if nothing)."""
    n = a.shape[0]
    t = np.empty(n)
    s = np.empty(n)
    for i in range(n):
        u = ((x - a[i, 0]) * d[i, 0] + (y - a[i, 1]) * d[i, 1]) / len2_div[i]
        t[i] = _clip01(u)
        s[i] = start[i] + t[i] * seg_len[i]
    if fresh:
        best, at = np.inf, -1
        for i in range(n):
            ox, oy = a[i, 0] + d[i, 0] * t[i] - x, a[i, 1] + d[i, 1] * t[i] - y
            q = ox * ox + oy * oy
            if at < 0 or q < best or (math.isnan(q) and not math.isnan(best)):
                best, at = q, i
        return s[at]
    best, at, tb = np.inf, -1, 0.0
    for i in range(n):
        c = s[i]
        c = lo if not (c > lo or math.isnan(c)) else c          # np.maximum(s, lo)
        c = hi if not (c < hi or math.isnan(c)) else c          # np.minimum(., hi)
        tw = _clip01((c - start[i]) / len_div[i])
        if end[i] < lo or start[i] > hi:
            q = np.inf
        else:
            ox, oy = a[i, 0] + d[i, 0] * tw - x, a[i, 1] + d[i, 1] * tw - y
            q = ox * ox + oy * oy
        if at < 0 or q < best or (math.isnan(q) and not math.isnan(best)):
            best, at, tb = q, i, tw
    if best <= look2:
        return start[at] + tb * seg_len[at]
    best, at = np.inf, -1
    for i in range(n):
        if s[i] >= lo:
            ox, oy = a[i, 0] + d[i, 0] * t[i] - x, a[i, 1] + d[i, 1] * t[i] - y
            q = ox * ox + oy * oy
        else:
            q = np.inf
        if at < 0 or q < best or (math.isnan(q) and not math.isnan(best)):
            best, at = q, i
    return s[at] if math.isfinite(best) else progress


@kernel
def peak_exponent(vs, ws, v, w, sv, sw, width2):
    """``-0.5 * (((vs - v) / sv) ** 2 + ((ws - w) / sw) ** 2) / width2``: what
    :func:`runtime.control.behaviours.peak` takes the exponential of."""
    out = np.empty(vs.shape[0])
    for k in range(vs.shape[0]):
        a = (vs[k] - v) / sv
        b = (ws[k] - w) / sw
        out[k] = -0.5 * (a * a + b * b) / width2
    return out


@kernel
def range_votes(votes, veto, ttc, moving, right, veto_time, horizon, keep, push):
    """:meth:`AvoidObstacles.ballot`'s range part, in place: moving arcs hitting within ``veto_time`` vetoed, arcs
    that hit voted at most ``-(1 - ttc / horizon)`` (``np.minimum``: NaN wins, a tie gives the second), with
    ``keep`` ``push`` (what is ahead times ``keep_right``) times the keep-right direction taken off, and the votes
    clipped to [-1, 1]."""
    for k in range(votes.shape[0]):
        t = ttc[k]
        if t <= veto_time and moving[k]:
            veto[k] = True
        x = votes[k]
        if math.isfinite(t):
            y = -(1.0 - t / horizon)
            if not (math.isnan(x) or x < y):
                x = y
        if keep:
            x = x - push * right[k]
        votes[k] = min(max(x, -1.0), 1.0) if not math.isnan(x) else x


@kernel
def weighted_sum(total, votes, weight):
    """``total += weight * clip(votes, -1, 1)`` in place (the arbiter's sum of one ballot); NaN votes stay NaN.
    Returns whether ``total`` holds a NaN afterwards (``np.isnan(total).any()`` without another pass)."""
    nan = False
    for k in range(total.shape[0]):
        x = votes[k]
        if not math.isnan(x):
            x = min(max(x, -1.0), 1.0)
        s = total[k] + weight * x
        total[k] = s
        if math.isnan(s):
            nan = True
    return nan


@kernel
def best_arc(grid, veto):
    """(scores, index of the best): the smoothed sum with vetoed arcs at -inf, and its first maximum (-1 when every
    arc is vetoed)."""
    n = veto.shape[0]
    scores = np.empty(n)
    best, at = -np.inf, -1
    for k in range(n):
        if veto[k]:
            scores[k] = -np.inf
        else:
            s = grid[k]
            scores[k] = s
            if at < 0 or s > best or (math.isnan(s) and not math.isnan(best)):
                best, at = s, k
    return scores, at
