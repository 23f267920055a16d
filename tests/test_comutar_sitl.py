"""Paper 003 in SITL (issues 17 and 32's acceptance): a Create 2 with no range sensor surveys a region among unmapped
pillars while avoiding them with robot 2's RPLIDAR laser scanner (as the paper's robot 2 reads a laser), both tasks
at once; robot 2's daemon is killed; the Create stands still, and its avoidance goes to the third robot's sonar.
So one run streams a laser (byte-exact emulator, driver, ``sensors:`` entry) and then a sonar ring to the Create."""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from runtime import config as C
from runtime.config.build import ConfigError
from sitl import fleet_config as FC

ROOT = Path(__file__).resolve().parents[1]
FLEET = ROOT / "configs" / "fleets" / "comutar_3.yaml"
LASER_FLEET = ROOT / "configs" / "fleets" / "comutar_3_laser.yaml"


def _load(tmp_path, **changes):
    from tests.sitl_util import shipped_fleet

    path = shipped_fleet(tmp_path, FLEET.name)
    data = yaml.safe_load(path.read_text())
    data["scenario"].update(changes)
    path.write_text(yaml.safe_dump(data))
    return FC.load_fleet(path)


@pytest.mark.parametrize("changes, key", [({"borrower": 9}, "scenario.borrower"), ({"avoid": [1, 7]}, "scenario.avoid[1]"),
                                          ({"region": [0, 0, 40, 4]}, "scenario.region"),
                                          ({"region": [0, 0, 4, 4], "spacing": 0.1}, "scenario.region"),
                                          ({"pillars": [{"center": [9, 9]}]}, "scenario.pillars[0]")])
def test_bad_scenarios_are_refused_naming_the_key(tmp_path, changes, key):
    with pytest.raises(ConfigError) as e:
        _load(tmp_path, **changes)
    assert key in str(e.value)


def test_the_shipped_robot_configs_build_comutar_agents_with_the_bases_sensors():
    from runtime.allocation import registry
    from runtime.allocation.agent import AgentContext
    from runtime.allocation.comutar.actions import sensors_of

    for name, kinds, readers in (("create2_comutar.yaml", (), ()), ("pioneer3dx_comutar.yaml", ("sonar",), ("sonar",)),
                                 ("pioneer3dx_comutar_laser.yaml", ("gps", "laser"), ("laser",))):
        cfg = C.load_robot(ROOT / "configs" / "robots" / name)
        assert cfg.allocation.method == "comutar"
        assert sensors_of(cfg.base, cfg.sensors) == kinds
        agent = registry.method("comutar").make(AgentContext(1, (2,), None, cfg.allocation, cfg.base, kinds))
        assert agent.catalogue.sensors == readers


@pytest.mark.slow
def test_the_borrower_surveys_without_touching_stops_when_its_sensor_dies_and_gets_another(tmp_path):
    """The three daemons lock-stepped in the test's process, devices and links as in a process fleet (about 20 s;
    as processes at 2x real time it took 75-90 s, and what the process boundary adds is tests/test_sitl_processes.py's)."""
    from sitl import launcher
    from tests.sitl_util import shipped_fleet

    f = launcher.build(shipped_fleet(tmp_path, LASER_FLEET.name), tmp_path / "run")
    assert [k for k, _ in f.robots[2].sensor_devs] == ["rplidar"]
    try:
        res = launcher.run_lockstep(f, timeout=400, picture=False)
        laser = f.robots[2].daemon.sensor_parts[0]
    finally:
        f.close()
    print({k: res[k] for k in ("verdict", "least_clearance", "kill", "sim_time")}, laser.stats)
    assert laser.kind == "laser" and laser.stats.scans > 100        # 5.5 revolutions a second until the kill
    assert res["goal_met"], res["verdict"]
    assert res["least_clearance"] > 0.0
    k = res["kill"]
    assert k["robot"] == 2 and k["new_provider"] == 3, k
    assert k["stood_still_after"] <= 1.0 and k["after"] <= 15.0, k
    survey = res["tasks"][-1]
    assert survey["label"] == "survey" and survey["state"] == "done"
    assert [who for _, who in res["tasks"][0]["awards"]][:2] == ["R1+R2", "R1+R3"]
