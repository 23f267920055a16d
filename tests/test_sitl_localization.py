"""Localization on a SITL run: the fused EKF pose beats GPS alone and wheel odometry alone.

Ground truth is the pybullet body; GPS is what the daemon's NMEA driver received from the emulated
receiver (converted to ENU); odometry is what the Create driver integrated from the emulated encoders,
placed at the operator-given start pose.  Odometry error comes from the simulated tyres' radius
tolerance and wheel slip in pybullet, GPS error from the receiver's noise.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from runtime.localization.enu import geodetic_to_enu
from sitl import launcher
from sitl.operator import Operator
from sitl.ports import free_udp_base
from tests.sitl_util import port_block
from tests.test_sitl_fleet import ROOT


def _fleet(tmp_path):
    base = free_udp_base(3, start=port_block())
    data = {
        "world": str(ROOT / "configs" / "worlds" / "arena_10m.yaml"),
        "robot": str(ROOT / "configs" / "robots" / "create2.yaml"),
        "robots": [{"id": 1, "start": [-4.0, -4.0, 0.0]}, {"id": 2, "start": [-4.0, 4.0, 0.0]},
                   {"id": 3, "start": [4.0, 0.0, 3.14159]}],
        "scenario": {"type": "formation", "positions": [[4.0, 4.0], [4.0, -4.0], [-4.0, 0.0]]},
        "base_port": base, "gcs": f"127.0.0.1:{base}", "seed": 3, "gps_noise": 0.5, "timeout": 120,
    }
    p = tmp_path / "fleet.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


@pytest.mark.slow
def test_fused_pose_beats_gps_and_odometry(tmp_path):
    f = launcher.build(_fleet(tmp_path), tmp_path / "run")
    err = {"fused": [], "gps": [], "odometry": []}
    try:
        from runtime.daemon import Daemon
        from runtime import config as C
        from runtime.clock import SimClock

        clock = SimClock(0.0)
        daemons = {}
        for r in f.robots.values():
            d = Daemon(C.load_robot(r.config_path), listen_socket=f.take_socket(r.id))
            d.open(0.0)
            daemons[r.id] = d
            poll = d.gps.poll

            def tapped(now, _poll=poll, _rid=r.id, _d=d):
                fixes = _poll(now)
                x, y, _ = f.true_pose(_rid)
                for fix in fixes:
                    e, n, _u = geodetic_to_enu(fix.lat, fix.lon, fix.alt, _d.cfg.datum)
                    err["gps"].append((e - x) ** 2 + (n - y) ** 2)
                return fixes
            d.gps.poll = tapped
        starts = {r.id: r.start for r in f.fleet.robots}
        op = Operator(f)              # hands the formation in over MAVLink
        while f.world.t < 60.0:
            f.advance_to(f.world.t + 0.05)
            clock.sleep_until(f.world.t)
            op.poll(f.world.t)
            for rid, d in daemons.items():
                d.step(clock.now())
                x, y, _ = f.true_pose(rid)
                if d.core.pose() is not None:
                    px, py, _ = d.core.pose()
                    err["fused"].append((px - x) ** 2 + (py - y) ** 2)
                sx, sy, syaw = starts[rid]
                o = d.base.odometry
                ox = sx + o.x * math.cos(syaw) - o.y * math.sin(syaw)
                oy = sy + o.x * math.sin(syaw) + o.y * math.cos(syaw)
                err["odometry"].append((ox - x) ** 2 + (oy - y) ** 2)
        travelled = [d.base.odometry.distance for d in daemons.values()]
        op.close()
    finally:
        for d in daemons.values():
            d.close()
        f.close()
    rmse = {k: math.sqrt(float(np.mean(v))) for k, v in err.items()}
    print(f"\nSITL localization RMSE over {f.world.t:.0f} s, 3 robots, {min(travelled):.1f}-"
          f"{max(travelled):.1f} m driven: fused {rmse['fused']:.3f} m, GPS alone {rmse['gps']:.3f} m, "
          f"odometry alone {rmse['odometry']:.3f} m")
    assert sum(travelled) > 15.0
    assert rmse["fused"] < rmse["gps"]
    assert rmse["fused"] < rmse["odometry"]
