"""A stock pymavlink client on the ground-station port sees every robot as a ground rover that moves."""
from __future__ import annotations

import pytest
from pymavlink import mavutil

from sitl import launcher
from tests.test_sitl_fleet import _fleet_copy


@pytest.mark.slow
def test_stock_pymavlink_client_sees_rovers_moving(tmp_path):
    fleet_path = _fleet_copy(tmp_path)
    f = launcher.build(fleet_path, tmp_path / "run")
    gcs_port = int(f.fleet.gcs.rsplit(":", 1)[1])
    client = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", source_system=255)
    seen_types: dict[int, set] = {}
    positions: dict[int, list] = {}

    def drain(_fleet):
        while True:
            m = client.recv_match(blocking=False)
            if m is None:
                return
            sysid = m.get_srcSystem()
            if m.get_type() == "HEARTBEAT":
                seen_types.setdefault(sysid, set()).add(m.type)
            elif m.get_type() == "GLOBAL_POSITION_INT":
                positions.setdefault(sysid, []).append((m.lat, m.lon))
    try:
        res = launcher.run_lockstep(f, timeout=60, on_step=drain)
    finally:
        f.close()
        client.close()
    assert res["valid"]
    for rid in (1, 2, 3, 4):
        assert seen_types.get(rid) == {mavutil.mavlink.MAV_TYPE_GROUND_ROVER}, seen_types
        lat0, lon0 = positions[rid][0]
        lat1, lon1 = positions[rid][-1]
        # moved by more than a metre (1e-7 deg ~ 1.1 cm): positions that move
        assert abs(lat1 - lat0) + abs(lon1 - lon0) > 90, (rid, positions[rid][0], positions[rid][-1])
        assert len(positions[rid]) >= 4 * res["sim_time"] * 0.9     # >= 4 Hz
