"""The robot's pose estimate from what it sensed: the EKF (:mod:`runtime.localization.ekf`) fed with wheel
odometry and position fixes, GPS fixes taken from WGS-84 to the fleet's ENU frame around the datum."""
from __future__ import annotations

import math
from collections.abc import Iterable

from runtime.localization.ekf import PoseEKF
from runtime.localization.enu import geodetic_to_enu


class PoseEstimate:
    def __init__(self, cfg, robot_id: int):
        self.cfg = cfg                           # runtime.config.RobotConfig: localization, datum
        self.ekf = PoseEKF(cfg.localization, robot_id=robot_id)
        if cfg.localization.initial_pose is not None:
            self.ekf.initialise(*cfg.localization.initial_pose)

    def update(self, dt: float, odometry: tuple[float, float] | None, fixes: Iterable) -> None:
        """One cycle: predict over ``dt`` s, then the base's new (v, w) if it gave one, then each valid GPS fix
        (an object with ``lat``, ``lon``, ``alt``); the first fix initialises an unknown position."""
        ekf = self.ekf
        if dt > 0 and ekf.initialised:
            ekf.predict(dt)
        if odometry is not None and ekf.initialised:
            ekf.update_odometry(*odometry)
        for fix in fixes:
            if not fix.valid:
                continue
            e, n, _ = geodetic_to_enu(fix.lat, fix.lon, fix.alt, self.cfg.datum)
            if not ekf.initialised:
                ekf.initialise(e, n, None)
            else:
                ekf.update_gps(e, n, self.cfg.localization.gps_sigma)

    def pose(self) -> tuple[float, float, float] | None:
        return self.ekf.pose() if self.ekf.initialised else None

    def velocity(self) -> tuple[float, float]:
        """(v east, v north) m/s; zero before the filter has a pose."""
        if not self.ekf.initialised:
            return (0.0, 0.0)
        x, y, th = self.ekf.pose()
        v = self.ekf.x[3]
        return (float(v * math.cos(th)), float(v * math.sin(th)))
