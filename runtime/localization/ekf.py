"""Pose EKF: unicycle model fusing wheel odometry and GPS (the predict and update of filterpy's
ExtendedKalmanFilter, written out here: filterpy requires matplotlib, which a robot does not install).

State ``(x, y, heading, v, w)`` in the fleet ENU frame (x east, y north, heading counter-clockwise
from east).  ``predict(dt)`` moves the state along the unicycle (midpoint heading) with white
linear and angular acceleration noise.

Odometry is a *measurement* of ``(v, w)``, not a control input.  Chosen because the base reports
body velocities (``Odometry.v, w``) at its own rate, independent of the control cycle that calls
``predict``; as a measurement its noise (``odom_sigma_v``, ``odom_sigma_w``) is weighed against GPS,
so the filter still predicts through an odometry dropout and a wheel that slips is outvoted
instead of being integrated blindly.

GPS ``(e, n)`` is gated: the squared Mahalanobis distance of the innovation against chi-square with
2 dof (``gate``, default 13.8 = 99.9 %).  Outliers are dropped and counted (``gps_rejected``).

The filter can be the one that is wrong: a robot carried away, or turned by a collision its wheels did not
see.  A turned robot steers by a wrong heading, so its GPS innovations pile up in one direction, some inside
the gate and some not, while the steering drives it further off.  Two tests catch it: ``max_rejections``
fixes in a row outside the gate, and the sum of the squared Mahalanobis distances of the last
``consistency_window`` fixes (accepted or not) above the chi-square quantile of 2 x window dof at
``consistency`` (a windowed NIS test: a consistent filter stays under it).  Either one *relocalises*
(``stats.relocalised``; ``stats.gps_resets`` counts the streaks): position from the fix, and heading
unknown again, found from motion as at start-up, because a filter that lost its position cannot vouch
for its heading.

Heading may start unknown (initialised from a GPS fix).  Until it is known the position is a random
walk whose step is the odometry speed, and the odometry path since then is kept beside the GPS
fixes; once the path has spread enough that the least-squares rotation aligning it with the fixes
has a standard deviation below ``resolve_sigma``, heading (and position) are set from that fit and
the full unicycle model takes over.  Heading is wrapped to (-pi, pi] after every step and in the
heading innovation.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np
import scipy.linalg

from runtime.config import LocalizationConfig
from runtime.localization.enu import wrap_angle
from runtime.log import get_logger

_H_POS = np.array([[1.0, 0, 0, 0, 0], [0, 1.0, 0, 0, 0]])
_H_VW = np.array([[0, 0, 0, 1.0, 0], [0, 0, 0, 0, 1.0]])
_H_HEADING = np.array([[0, 0, 1.0, 0, 0]])
_MIN_SIGMA = 1e-3          # floor on measurement sigmas (a zero sigma makes S singular)
_MAX_STEP = 0.1            # s; longer predictions are split


@dataclass
class EkfStats:
    predictions: int = 0
    odometry_updates: int = 0
    gps_accepted: int = 0
    gps_rejected: int = 0      # dropped by the Mahalanobis gate
    gps_resets: int = 0        # relocalised after max_rejections rejections in a row
    relocalised: int = 0       # position from GPS and heading found again (a streak or the window test)
    heading_updates: int = 0
    heading_rejected: int = 0
    heading_resolved: int = 0  # times heading was found from motion
    nonfinite: int = 0         # measurements or dt with nan/inf, ignored


def chi2_quantile(p: float, dof: int) -> float:
    """Chi-square quantile by Wilson and Hilferty's cube-root normal approximation (within 1.2 % of the exact
    value for dof >= 10 at p <= 0.9999; 52.66 against 52.39 for the default 20 dof), to keep scipy.stats out of
    the daemon."""
    z = NormalDist().inv_cdf(p)
    a = 2.0 / (9.0 * dof)
    return dof * (1.0 - a + z * math.sqrt(a)) ** 3


class _UnicycleEKF:
    """EKF whose state transition is the unicycle; ``u = (dt, heading_known)``.  ``F`` and ``Q`` are set before
    each :meth:`predict`; :meth:`update` uses the Joseph form, as filterpy's ``ExtendedKalmanFilter`` does."""

    def __init__(self, dim_x: int, dim_z: int):
        self.x = np.zeros(dim_x)
        self.P = np.eye(dim_x)
        self.F = np.eye(dim_x)
        self.Q = np.eye(dim_x)
        self._I = np.eye(dim_x)

    def predict_x(self, u) -> None:
        dt, known = u
        x, y, th, v, w = self.x
        if known:
            thm = th + 0.5 * w * dt
            self.x = np.array([x + v * math.cos(thm) * dt, y + v * math.sin(thm) * dt,
                               wrap_angle(th + w * dt), v, w])
        else:
            self.x = np.array([x, y, th, v, w])

    def predict(self, u) -> None:
        self.predict_x(u)
        self.P = self.F @ self.P @ self.F.T + self.Q

    def update(self, z, HJacobian, Hx, R, residual=np.subtract) -> None:
        H = HJacobian(self.x)
        PHT = self.P @ H.T
        K = PHT @ scipy.linalg.inv(H @ PHT + R)       # scipy's inverse, as filterpy's: the same bits
        self.x = self.x + K @ residual(z, Hx(self.x))
        I_KH = self._I - K @ H
        self.P = I_KH @ self.P @ I_KH.T + K @ R @ K.T


class PoseEKF:
    """Unicycle EKF over (x, y, heading, v, w); see the module docstring for the model."""

    def __init__(self, cfg: LocalizationConfig = LocalizationConfig(), *, accel_sigma: float = 0.5,
                 yaw_accel_sigma: float = 1.0, heading_noise: float = 0.05, resolve_sigma: float = 0.3,
                 heading_gate: float = 10.83, max_rejections: int = 10, robot_id=None):
        self.cfg = cfg
        self.accel_sigma = accel_sigma            # m/s^2, white linear acceleration
        self.yaw_accel_sigma = yaw_accel_sigma    # rad/s^2, white angular acceleration
        self.heading_noise = heading_noise        # rad/sqrt(s), slip not seen by the odometry
        self.resolve_sigma = resolve_sigma        # rad; heading-from-motion accepted below this
        self.heading_gate = heading_gate          # chi^2(1) for update_heading, default 99.9 %
        self.max_rejections = max_rejections
        self.stats = EkfStats()
        self.log = get_logger("ekf", robot_id)
        self.kf = _UnicycleEKF(dim_x=5, dim_z=2)
        self.kf.x = np.zeros(5)
        self.initialised = False
        self.heading_known = False
        self._in_a_row = 0
        self._nis: deque = deque(maxlen=max(1, cfg.consistency_window))   # squared Mahalanobis d of recent fixes
        self._nis_gate = chi2_quantile(cfg.consistency, 2 * cfg.consistency_window) if cfg.consistency_window else 0.0
        self._rel = np.zeros(3)                   # odometry path since heading became unknown
        self._track: deque = deque(maxlen=100)    # (rel x, rel y, e, n, sigma^2) per accepted fix

    # ------------------------------------------------------------------ state
    @property
    def x(self) -> np.ndarray:
        """State vector (x, y, heading, v, w)."""
        return self.kf.x

    @property
    def covariance(self) -> np.ndarray:
        """5x5 state covariance (a copy)."""
        return self.kf.P.copy()

    @property
    def gps_rejected(self) -> int:
        return self.stats.gps_rejected

    def pose(self) -> tuple[float, float, float]:
        """(x, y, heading); heading is a placeholder 0.0 while ``heading_known`` is False."""
        if not self.initialised:
            raise RuntimeError("PoseEKF.pose() before initialise() or the first GPS fix")
        x, y, th = self.kf.x[:3]
        return float(x), float(y), float(th)

    def initialise(self, x: float, y: float, heading: float | None = None, sigma_xy: float | None = None,
                   sigma_heading: float = 0.1) -> None:
        """Start at (x, y); heading None means unknown until the robot has moved.  Non-finite input
        is counted and leaves the filter as it was."""
        if not all(math.isfinite(v) for v in (x, y, 0.0 if heading is None else heading)):
            self.stats.nonfinite += 1
            return
        sxy = self.cfg.gps_sigma if sigma_xy is None else sigma_xy
        known = heading is not None
        self.kf.x = np.array([x, y, wrap_angle(heading) if known else 0.0, 0.0, 0.0], dtype=float)
        self.kf.P = np.diag([sxy ** 2, sxy ** 2, sigma_heading ** 2 if known else math.pi ** 2, 0.1 ** 2, 0.1 ** 2])
        self.initialised, self.heading_known = True, known
        self._in_a_row = 0
        self._nis.clear()
        self._rel[:] = 0.0
        self._track.clear()

    # ------------------------------------------------------------------ predict
    def predict(self, dt: float) -> None:
        """Advance the state by ``dt`` seconds (no-op before initialisation or for dt <= 0)."""
        if not self.initialised:
            return
        if not math.isfinite(dt):
            self.stats.nonfinite += 1
            return
        if dt <= 0:
            return
        steps = max(1, math.ceil(dt / _MAX_STEP))
        for _ in range(steps):
            self._predict_step(dt / steps)
        self.stats.predictions += 1

    def _predict_step(self, dt: float) -> None:
        _, _, th, v, w = self.kf.x
        qa, qw = self.accel_sigma ** 2, self.yaw_accel_sigma ** 2
        F = np.eye(5)
        if self.heading_known:
            thm = th + 0.5 * w * dt
            c, s = math.cos(thm), math.sin(thm)
            F[0, 2], F[0, 3], F[0, 4] = -v * s * dt, c * dt, -v * s * dt * dt / 2
            F[1, 2], F[1, 3], F[1, 4] = v * c * dt, s * dt, v * c * dt * dt / 2
            F[2, 4] = dt
            G = np.array([[c * dt * dt / 2, 0], [s * dt * dt / 2, 0], [0, dt * dt / 2], [dt, 0], [0, dt]])
            Q = G @ np.diag([qa, qw]) @ G.T
            Q[2, 2] += self.heading_noise ** 2 * dt
        else:
            # direction unknown: the position diffuses at the odometry speed (1 s correlation time)
            thm = self._rel[2] + 0.5 * w * dt
            self._rel += (v * math.cos(thm) * dt, v * math.sin(thm) * dt, w * dt)
            walk = (v * v * 1.0 + qa * dt ** 2 / 4) * dt
            Q = np.diag([walk, walk, 0.0, qa * dt * dt, qw * dt * dt])
        self.kf.F = F
        self.kf.Q = Q
        self.kf.predict(u=(dt, self.heading_known))
        self._tidy()

    # ------------------------------------------------------------------ updates
    def update_odometry(self, v: float, w: float) -> None:
        """Wheel odometry as a measurement of (v, w) with ``odom_sigma_v``, ``odom_sigma_w``."""
        if not self.initialised:
            return
        if not (math.isfinite(v) and math.isfinite(w)):
            self.stats.nonfinite += 1
            return
        R = np.diag([max(self.cfg.odom_sigma_v, _MIN_SIGMA) ** 2, max(self.cfg.odom_sigma_w, _MIN_SIGMA) ** 2])
        self.kf.update(np.array([v, w], dtype=float), lambda s: _H_VW, lambda s: _H_VW @ s, R=R)
        self._tidy()
        self.stats.odometry_updates += 1

    def update_gps(self, e: float, n: float, sigma: float | None = None) -> bool:
        """Fuse a GPS position (ENU metres, ``sigma`` per axis, default ``gps_sigma``).  Returns False
        if it was gated out (or not finite); the first fix initialises the filter."""
        if not (math.isfinite(e) and math.isfinite(n)) or (sigma is not None and not math.isfinite(sigma)):
            self.stats.nonfinite += 1
            return False
        sigma = max(self.cfg.gps_sigma if sigma is None else sigma, _MIN_SIGMA)
        if not self.initialised:
            self.initialise(e, n, None, sigma)
            self.stats.gps_accepted += 1
            return True
        z = np.array([e, n], dtype=float)
        R = np.eye(2) * sigma ** 2
        d2 = self._mahalanobis2(z - self.kf.x[:2], _H_POS, R)
        if d2 > self.cfg.gate:
            self.stats.gps_rejected += 1
            self._in_a_row += 1
            self.log.debug("gps fix (%.2f, %.2f) rejected: d2 %.1f > gate %.1f", e, n, d2, self.cfg.gate)
            if self._in_a_row >= self.max_rejections:
                self.stats.gps_resets += 1
                self._relocalise(e, n, sigma, f"{self._in_a_row} gps fixes in a row outside the gate")
            else:
                self._check_consistency(d2, e, n, sigma)
            return False
        if self._check_consistency(d2, e, n, sigma):
            return True
        self._in_a_row = 0
        self.kf.update(z, lambda s: _H_POS, lambda s: _H_POS @ s, R=R)
        self._tidy()
        self.stats.gps_accepted += 1
        if not self.heading_known:
            self._track.append((self._rel[0], self._rel[1], e, n, sigma ** 2))
            self._resolve_heading()
        return True

    def update_heading(self, heading: float, sigma: float) -> bool:
        """Fuse an absolute heading (compass, GPS course when driving forward); the innovation is
        wrapped.  Gated with chi-square 1 dof (``heading_gate``).  If heading is still unknown it is
        taken as is."""
        if not self.initialised:
            return False
        if not (math.isfinite(heading) and math.isfinite(sigma)):
            self.stats.nonfinite += 1
            return False
        sigma = max(sigma, _MIN_SIGMA)
        if not self.heading_known:
            self._set_heading(wrap_angle(heading), sigma ** 2)
            self.stats.heading_updates += 1
            return True
        R = np.array([[sigma ** 2]])
        y = np.array([wrap_angle(heading - self.kf.x[2])])
        if self._mahalanobis2(y, _H_HEADING, R) > self.heading_gate:
            self.stats.heading_rejected += 1
            return False
        self.kf.update(np.array([heading], dtype=float), lambda s: _H_HEADING, lambda s: _H_HEADING @ s, R=R,
                       residual=lambda a, b: np.array([wrap_angle(float(a[0] - b[0]))]))
        self._tidy()
        self.stats.heading_updates += 1
        return True

    # ------------------------------------------------------------------ internals
    def _mahalanobis2(self, y: np.ndarray, H: np.ndarray, R: np.ndarray) -> float:
        S = H @ self.kf.P @ H.T + R
        return float(y @ np.linalg.solve(S, y))

    def _tidy(self) -> None:
        self.kf.x = np.asarray(self.kf.x, dtype=float).reshape(5)
        self.kf.x[2] = wrap_angle(float(self.kf.x[2]))
        self.kf.P = 0.5 * (self.kf.P + self.kf.P.T)

    def _set_heading(self, heading: float, var: float) -> None:
        P = self.kf.P
        P[2, :] = 0.0
        P[:, 2] = 0.0
        P[2, 2] = var
        self.kf.x[2] = heading
        self.heading_known = True
        self._track.clear()

    def _check_consistency(self, d2: float, e: float, n: float, sigma: float) -> bool:
        """Windowed NIS test; relocalises (True) when it fails.  Each fix counts at most ``gate``, so one wild fix
        does not fail it: it takes fixes that disagree one after the other."""
        if not (self.heading_known and self.cfg.consistency_window):
            return False
        self._nis.append(min(d2, self.cfg.gate))
        total = sum(self._nis)
        if len(self._nis) < self._nis.maxlen or total <= self._nis_gate:
            return False
        self._relocalise(e, n, sigma, f"the last {len(self._nis)} gps fixes disagree with the filter "
                         f"(sum of d2 {total:.0f} > {self._nis_gate:.0f})")
        return True

    def _relocalise(self, e: float, n: float, sigma: float, why: str) -> None:
        """Position from the fix, heading unknown (its last value kept as the guess the robot steers by until
        motion gives it again)."""
        self.stats.relocalised += 1
        self.log.warning("%s: position reset to (%.2f, %.2f), heading to be found again from motion", why, e, n)
        P = self.kf.P
        P[:3, :] = 0.0
        P[:, :3] = 0.0
        P[0, 0] = P[1, 1] = sigma ** 2
        P[2, 2] = math.pi ** 2
        self.kf.x[:2] = (e, n)
        self.heading_known = False
        self._in_a_row = 0
        self._nis.clear()
        self._rel[:] = 0.0
        self._track.clear()

    def _resolve_heading(self) -> None:
        """Least-squares rotation between the odometry path and the GPS fixes since heading was lost."""
        if len(self._track) < 5:
            return
        t = np.array(self._track)
        p, g = t[:, 0:2], t[:, 2:4]
        pm, gm = p.mean(axis=0), g.mean(axis=0)
        pc, gc = p - pm, g - gm
        spread = float((pc ** 2).sum())
        if spread <= 0:
            return
        var = 2.0 * float(t[:, 4].mean()) / spread    # x2 for the odometry's own error
        if var > self.resolve_sigma ** 2:
            return
        rot = math.atan2(float((pc[:, 0] * gc[:, 1] - pc[:, 1] * gc[:, 0]).sum()),
                         float((pc * gc).sum()))
        c, s = math.cos(rot), math.sin(rot)
        lever = self._rel[:2] - pm
        pos = gm + np.array([c * lever[0] - s * lever[1], s * lever[0] + c * lever[1]])
        heading = wrap_angle(rot + self._rel[2])
        P = self.kf.P
        P[:3, :] = 0.0
        P[:, :3] = 0.0
        P[0, 0] = P[1, 1] = float(t[:, 4].mean()) / len(t) + var * float(lever @ lever)
        P[2, 2] = var
        self.kf.x[:3] = (pos[0], pos[1], heading)
        self.heading_known = True
        self.stats.heading_resolved += 1
        self.log.info("heading %.2f rad found from %d fixes over %.1f m of motion (sigma %.3f rad)",
                      heading, len(t), math.sqrt(spread / len(t)) * 2, math.sqrt(var))
        self._track.clear()
