"""Acceptance: unmodified pycreate2 opens a SITL robot's pty named in the manifest of
`mrta sitl run --devices-only`, drives the pybullet robot and reads its sensors."""
from __future__ import annotations

import math
import signal
import time

import pytest

from tests.sitl_util import devices_only
from tests.test_sitl_fleet import _fleet_copy


@pytest.mark.slow
def test_pycreate2_drives_a_sitl_robot_from_the_manifest(tmp_path):
    pycreate2 = pytest.importorskip("pycreate2")
    sitl, robots = devices_only(_fleet_copy(tmp_path), tmp_path)
    try:
        robot = robots[0]
        bot = pycreate2.Create2(robot["base"]["port"], baud=robot["base"]["baudrate"])
        bot.start()
        bot.safe()
        first = bot.get_sensors()
        bot.drive_direct(150, 150)            # mm/s, right and left
        time.sleep(2.0)
        bot.drive_stop()
        time.sleep(0.3)
        last = bot.get_sensors()
        del bot                                # pycreate2's __del__ stops the wheels and closes the port
        # encoders advanced by ~2 s x 150 mm/s on both wheels (508.8 counts per 72 mm wheel turn)
        counts_per_m = 508.8 / (math.pi * 0.072)
        for name in ("encoder_counts_left", "encoder_counts_right"):
            moved = (getattr(last, name) - getattr(first, name)) % 65536 / counts_per_m
            assert 0.15 < moved < 0.6, (name, moved)
        assert 12.0 < last.voltage / 1000 < 17.0
        assert last.open_interface_mode == 2   # safe
    finally:
        sitl.send_signal(signal.SIGINT)        # Ctrl-C stops everything cleanly
        out, _ = sitl.communicate(timeout=20)
    assert sitl.returncode == 0, out
