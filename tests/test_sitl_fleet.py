"""End-to-end SITL: the world, emulated devices and real daemons, as `make run` runs them."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from sitl import launcher
from sitl.ports import free_udp_base
from tests.sitl_util import port_block

ROOT = Path(__file__).resolve().parents[1]
FLEET4 = ROOT / "configs" / "fleets" / "create2_4.yaml"


def _fleet_copy(tmp_path, **changes) -> Path:
    import yaml
    data = yaml.safe_load(FLEET4.read_text())
    data["world"] = str(ROOT / "configs" / "worlds" / "arena_10m.yaml")
    data["robot"] = str(ROOT / "configs" / "robots" / "create2.yaml")
    base = free_udp_base(len(data["robots"]), start=port_block())
    data["base_port"] = base
    data["gcs"] = f"127.0.0.1:{base}"
    data.update(changes)
    p = tmp_path / "fleet.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


@pytest.mark.slow
def test_lockstep_fleet_reaches_formation_and_is_repeatable(tmp_path):
    results = []
    for k in range(2):
        f = launcher.build(_fleet_copy(tmp_path), tmp_path / f"run{k}", seed=7)
        try:
            results.append(launcher.run_lockstep(f, timeout=90, picture=False))
        finally:
            f.close()
    res = results[0]
    print(json.dumps(res, indent=1, default=str))
    assert res["valid"], res
    assert all(e < 0.25 for e in res["final_error"].values()), res["final_error"]
    assert res["global_cost"] >= res["optimum"] - 1e-9
    # same seed, same run: same assignment, same final positions to the millimetre
    assert results[1]["assignment"] == res["assignment"]
    for rid, err in res["final_error"].items():
        assert abs(results[1]["final_error"][rid] - err) < 1e-3


def test_manifest_lists_every_robot(tmp_path):
    manifest = tmp_path / "m.json"
    f = launcher.build(_fleet_copy(tmp_path), tmp_path / "run", manifest)
    try:
        data = json.loads(manifest.read_text())
        assert [r["id"] for r in data["robots"]] == [1, 2, 3, 4]
        for r in data["robots"]:
            assert Path(r["base"]["port"]).exists() and Path(r["gps"]["device"]).exists()
            assert r["system_id"] == r["id"] and r["mavlink_udp"].startswith("127.0.0.1:")
            assert Path(r["config"]).is_file()
        assert data["ground_station"].startswith("127.0.0.1:")
    finally:
        f.close()


@pytest.mark.slow
def test_fleet_plans_around_boxes(tmp_path):
    """Bids are A* path lengths on the world map and robots drive the planned paths without
    getting stuck on the boxes."""
    import yaml
    src = ROOT / "configs" / "fleets" / "create2_4_boxes.yaml"
    data = yaml.safe_load(src.read_text())
    data["world"] = str(ROOT / "configs" / "worlds" / "boxes_10m.yaml")
    data["robot"] = str(ROOT / "configs" / "robots" / "create2.yaml")
    base = free_udp_base(len(data["robots"]), start=port_block())
    data["base_port"], data["gcs"] = base, f"127.0.0.1:{base}"
    path = tmp_path / "boxes.yaml"
    path.write_text(yaml.safe_dump(data))
    f = launcher.build(path, tmp_path / "run")
    try:
        res = launcher.run_lockstep(f, timeout=120, picture=False)
    finally:
        f.close()
    assert res["valid"], res
    assert all(e < 0.25 for e in res["final_error"].values()), res["final_error"]
    assert res["sim_time"] < 120


@pytest.mark.slow
def test_a_robot_that_never_comes_up_is_treated_as_lost_and_the_rest_converge(tmp_path):
    """Robot 4 is configured as every daemon's peer but never starts.  The link only times out peers it
    has heard, so without comms.startup_grace the epsilon auction would wait for robot 4's rung for ever."""
    from runtime import config as C
    from runtime.daemon import Daemon
    from sitl.operator import Operator
    f = launcher.build(_fleet_copy(tmp_path), tmp_path / "run", seed=3)
    daemons = {}
    op = Operator(f)              # hands the formation to robot 1 over MAVLink
    try:
        daemons = {rid: Daemon(C.load_robot(r.config_path), listen_socket=f.take_socket(rid))
                   for rid, r in f.robots.items() if rid != 4}
        grace = daemons[1].cfg.comms.startup_grace
        for d in daemons.values():
            d.open(f.world.t)
        while f.world.t < grace + 60:
            f.advance_to(f.world.t + 0.05)
            op.poll(f.world.t)
            for d in daemons.values():
                d.step(f.world.t)
            if f.world.t > grace and all(d.core.agent.converged for d in daemons.values()):
                break
        assert all(d.core.agent.converged for d in daemons.values())
        assert all(d.core.stats.peers_lost == [4] for d in daemons.values())
        held = [c.task_id for d in daemons.values() for c in d.core.agent.commitments]
        assert len(held) == 3 and len(set(held)) == 3
    finally:
        op.close()
        for d in daemons.values():
            d.close()
        f.close()
