"""Configs: every shipped file loads; every kind of mistake is one line naming file and key."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from hypothesis import given, settings, strategies as st

from runtime import config as C
from runtime.config import ConfigError
from runtime.errors import InputError
from runtime.drivers.registry import BASES
from sitl import fleet_config as FC

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"


@pytest.mark.parametrize("path", sorted((CONFIGS / "robots").glob("*.yaml")), ids=lambda p: p.name)
def test_shipped_robot_configs_load(path):
    cfg = C.load_robot(path)
    assert cfg.source == str(path)
    assert 1 <= cfg.robot.id <= 250


@pytest.mark.parametrize("path", sorted((CONFIGS / "worlds").glob("*.yaml")), ids=lambda p: p.name)
def test_shipped_world_configs_load(path):
    cfg = C.load_world(path)
    assert cfg.size[0] > 0 and cfg.size[1] > 0


@pytest.mark.parametrize("path", sorted((CONFIGS / "fleets").glob("*.yaml")), ids=lambda p: p.name)
def test_shipped_fleet_configs_load(path):
    fleet = FC.load_fleet(path)
    C.load_world(fleet.world)
    for r in fleet.robots:
        C.load_robot(fleet.template(r.id))
    if fleet.scenario.type == "formation":
        assert len(fleet.robots) == len(fleet.scenario.positions)


def test_every_shipped_config_is_covered():
    kinds = {p.parent.name for p in CONFIGS.rglob("*.yaml")}
    assert kinds <= {"robots", "worlds", "fleets"}


def _write(tmp_path, data, name="robot.yaml"):
    p = tmp_path / name
    p.write_text(yaml.safe_dump(data) if not isinstance(data, str) else data)
    return p


@pytest.mark.parametrize(
    "data, key, expected",
    [
        ({"robot": {"idd": 3}}, "robot.idd", "no such key"),
        ({"robot": {"id": 0}}, "robot.id", "[1, 250]"),
        ({"robot": {"id": 2.5}}, "robot.id", "an integer"),
        ({"base": {"model": "roomba"}}, "base.model", "one of create1|create2"),
        ({"base": {"max_speed": 0.9}}, "base.max_speed", "[0.01, 0.5]"),
        ({"control": {"lookahead": "far"}}, "control.lookahead", "a number"),
        ({"gps": {"enabled": "yes"}}, "gps.enabled", "true/false"),
        ({"comms": {"peers": [{"id": 2}, {"address": "x"}]}}, "comms.peers[1].id", "required"),
        ({"localization": {"initial_pose": [1, 2]}}, "localization.initial_pose", "a list of 3 numbers"),
        ({"localization": {"initial_pose": [1e300, 1e300, 0]}}, "localization.initial_pose[0]",
         "a number in [-50000, 50000], got 1e+300"),
        ({"localization": {"initial_pose": [0, -60000, 0]}}, "localization.initial_pose[1]", "[-50000, 50000]"),
        ({"localization": {"initial_pose": [0, 0, 1e300]}}, "localization.initial_pose[2]", "[-7, 7]"),
        ({"datum": {"lat": 91}}, "datum.lat", "[-90, 90]"),
        ({"control": {"rate": float("nan")}}, "control.rate", "a number"),
    ],
)
def test_bad_robot_config_names_file_and_key(tmp_path, data, key, expected):
    path = _write(tmp_path, data)
    with pytest.raises(ConfigError) as info:
        C.load_robot(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: {key}: expected"), msg
    assert expected in msg
    assert "\n" not in msg


def test_top_level_not_a_mapping(tmp_path):
    path = _write(tmp_path, [1, 2])
    with pytest.raises(ConfigError) as info:
        C.load_robot(path)
    assert str(info.value) == f"{path}: expected a mapping, got [1, 2]"


def test_bad_yaml_and_missing_file(tmp_path):
    path = _write(tmp_path, "robot: [1, 2\n")
    with pytest.raises(ConfigError, match="line 2: expected valid YAML"):
        C.load_robot(path)
    with pytest.raises(ConfigError, match="readable YAML file"):
        C.load_robot(tmp_path / "nope.yaml")


def test_fleet_checks_paths_and_ids(tmp_path):
    good = yaml.safe_load((CONFIGS / "fleets" / "create2_4.yaml").read_text())
    bad = dict(good, world="../nowhere.yaml")
    path = _write(tmp_path, bad, "fleet.yaml")
    with pytest.raises(ConfigError, match=r"fleet.yaml: world: expected a path"):
        FC.load_fleet(path)
    dup = dict(good, world=str(CONFIGS / "worlds" / "arena_10m.yaml"),
               robot=str(CONFIGS / "robots" / "create2.yaml"),
               robots=[{"id": 1}, {"id": 1}])
    path = _write(tmp_path, dup, "fleet.yaml")
    with pytest.raises(ConfigError, match="robots: expected unique robot ids"):
        FC.load_fleet(path)


def test_cli_exits_2_with_one_line(tmp_path, capsys):
    from runtime.cli import main
    path = _write(tmp_path, {"robot": {"id": 999}})
    code = main(["daemon", str(path), "--check"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err.count("\n") == 0 and "robot.id" in err and str(path) in err


def test_round_trip_to_dict():
    cfg = C.load_robot(CONFIGS / "robots" / "create2.yaml")
    again = C.from_dict(C.RobotConfig, C.to_dict(cfg), cfg.source)
    assert again == cfg


yaml_values = st.recursive(
    st.none() | st.booleans() | st.integers(-10**6, 10**6) | st.floats(allow_nan=True) | st.text(max_size=8),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4),
    max_leaves=20,
)
section_names = st.sampled_from(["robot", "base", "gps", "localization", "comms", "control", "allocation", "datum"])


@settings(max_examples=300, deadline=None)
@given(st.dictionaries(section_names | st.text(max_size=6), yaml_values, max_size=5))
def test_random_config_data_never_crashes(data):
    """Whatever the YAML holds, loading gives a config or a ConfigError - nothing else."""
    try:
        C.from_dict(C.RobotConfig, data, "random.yaml")
    except ConfigError as exc:
        assert str(exc).startswith("random.yaml: ")


@pytest.mark.parametrize("data, key, allowed", [
    ({"allocation": {"method": "greedy"}}, "allocation.method", "bs|rtma|auction|coalition|dr|comutar"),
    ({"base": {"type": "roomba"}}, "base.type", "|".join(BASES)),
])
def test_a_wrong_union_tag_names_the_allowed_values(tmp_path, data, key, allowed):
    path = _write(tmp_path, data)
    with pytest.raises(ConfigError) as info:
        C.load_robot(path)
    assert str(info.value).startswith(f"{path}: {key}: expected one of {allowed}, got ")


def test_each_method_s_options_are_its_config_schema(tmp_path):
    """allocation: takes the keys of the chosen method's options and no other's."""
    cfg = C.load_robot(_write(tmp_path, {"allocation": {"method": "auction", "theta": 4.0}}))
    assert cfg.allocation.method == "auction" and cfg.allocation.theta == 4.0
    with pytest.raises(ConfigError, match=r"allocation.theta: expected no such key"):
        C.load_robot(_write(tmp_path, {"allocation": {"method": "bs", "theta": 4.0}}))


@pytest.mark.parametrize("scenario, key, expected", [
    ({"type": "parade"}, "scenario.type", "one of formation|mission"),
    ({"type": "mission", "tasks": [{"kind": "dance", "x": 0, "y": 0}]}, "scenario.tasks[0].kind",
     "one of goto|rendezvous"),
    ({"type": "mission", "tasks": [{"kind": "rendezvous", "x": 0, "y": 0, "robots": 12}]},
     "scenario.tasks[0].robots", "[1, 8]"),
    ({"type": "mission", "tasks": [{"x": 0, "y": 0, "to": 9}]}, "scenario.tasks[0].to", "a robot of the fleet"),
    ({"type": "formation"}, "scenario.positions", "at least one position"),
])
def test_bad_scenarios_name_the_key(tmp_path, scenario, key, expected):
    good = yaml.safe_load((CONFIGS / "fleets" / "create2_4.yaml").read_text())
    data = dict(good, world=str(CONFIGS / "worlds" / "arena_10m.yaml"), robot=str(CONFIGS / "robots" / "create2.yaml"),
                scenario=scenario)
    path = _write(tmp_path, data, "fleet.yaml")
    with pytest.raises(ConfigError) as info:
        FC.load_fleet(path)
    assert str(info.value).startswith(f"{path}: {key}: expected") and expected in str(info.value), str(info.value)


def test_an_unknown_key_with_odd_characters_is_shown_quoted_on_one_line():
    with pytest.raises(ConfigError) as info:
        C.from_dict(C.RobotConfig, {"control": {"rate\n": 1}}, "odd.yaml")
    assert str(info.value).startswith("odd.yaml: control.'rate\\n': expected no such key") and "\n" not in str(info.value)


# --------------------------------------------------------------------------- hostile files (issue 14, item 6)

def _alias_bomb(depth: int = 8, width: int = 10) -> str:
    """``robot.name``: a list of aliases ``depth`` levels deep, ``width`` per level (width^depth values expanded)."""
    def level(i):
        if i == 0:
            return "&a0 [" + ",".join(["x"] * width) + "]"
        return f"&a{i} [" + level(i - 1) + "," + ",".join([f"*a{i - 1}"] * (width - 1)) + "]"
    return "robot:\n  name: " + level(depth) + "\n"


def _one_config_error(path, loader=C.load_robot) -> str:
    with pytest.raises(ConfigError) as info:
        loader(path)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith(f"{path}: "), msg
    return msg


@pytest.mark.parametrize("text, where, expected", [
    (b"robot:\n  name: \xff\xfe\n", "line 2", "UTF-8 text"),
    ("control:\n  rate: 1" + "0" * 400 + "\n", "control.rate", "a number (at most"),
    ("control:\n  rate: 1" + "0" * 5000 + "\n", "line 2", "an integer of at most 1000 characters"),
    ("robot:\n  name: " + "[" * 3000 + "]" * 3000 + "\n", "line 2", "levels of nesting"),
    ("robot: " + "{a: " * 3000 + "1" + "}" * 3000 + "\n", "line 1", "levels of nesting"),
    ("robot:\n  name: &a [*a]\n", "line 2", "a recursive alias"),
    ("robot:\n  name: 2020-13-45\n", "line 2", "a value its tag allows"),
    (b"\x00robot: {}\n", "document", "valid YAML"),            # found by the fuzz suite
])
def test_hostile_yaml_is_one_line_naming_file_and_line_or_key(tmp_path, text, where, expected):
    path = tmp_path / "robot.yaml"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    msg = _one_config_error(path)
    assert msg.startswith(f"{path}: {where}: expected") and expected in msg, msg


def test_a_config_file_larger_than_the_limit_is_refused_unread(tmp_path):
    from runtime.config import build
    path = tmp_path / "robot.yaml"
    path.write_text("# padding\n" * (build.MAX_BYTES // 10 + 1))
    assert "at most" in _one_config_error(path)


def test_an_alias_bomb_fails_fast_and_small(tmp_path):
    """600 bytes standing for 10^9 values: refused while composing, in a process with 1 GB of address space."""
    path = tmp_path / "bomb.yaml"
    path.write_text(_alias_bomb())
    assert len(path.read_bytes()) < 700
    code = ("import resource, sys; resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30)); "
            "from runtime.cli import main; sys.exit(main(sys.argv[1:]))")
    proc = subprocess.run([sys.executable, "-c", code, "daemon", str(path), "--check"], cwd=ROOT, timeout=60,
                          capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert proc.returncode == 2, proc.stderr[-500:]
    assert proc.stderr.count("\n") == 1 and "values once aliases are expanded" in proc.stderr, proc.stderr


def test_aliases_within_the_budget_still_load(tmp_path):
    path = _write(tmp_path, "base: &b {type: create_oi, max_speed: 0.4}\nrobot: {name: r}\n"
                            "control: {rate: &r 20}\nlocalization: {gps_sigma: *r}\n")
    cfg = C.load_robot(path)
    assert cfg.base.max_speed == 0.4 and cfg.localization.gps_sigma == 20


def test_an_error_never_formats_a_huge_value_whole():
    shared = [0] * 10
    for _ in range(8):
        shared = [shared] * 10                     # 10^9 values once expanded
    with pytest.raises(ConfigError) as info:
        C.from_dict(C.RobotConfig, {"robot": {"name": shared}}, "huge.yaml")
    got = str(info.value).split(", got ", 1)[1]
    assert got == ("[" * 9 + "0, " * 9 + "0], [" + "0, " * 10)[:60] + "...", got
    assert C.short_repr(10 ** 5000) == "<an integer of 5001 digits>"
    assert C.short_repr({"a": (1,), "b": "x" * 100}) == repr({"a": (1,), "b": "x" * 100})[:60] + "..."
    assert C.short_repr([1, (2,), {"k": None}, "s"]) == repr([1, (2,), {"k": None}, "s"])


def _fleet(tmp_path, **change):
    good = yaml.safe_load((CONFIGS / "fleets" / "create2_4.yaml").read_text())
    data = dict(good, world=str(CONFIGS / "worlds" / "arena_10m.yaml"), robot=str(CONFIGS / "robots" / "create2.yaml"))
    data.update(change)
    return _write(tmp_path, data, "fleet.yaml")


@pytest.mark.parametrize("change, key, expected", [
    ({"robots": []}, "robots", "at least one robot"),
    ({"seed": -1}, "seed", "[0, 4294967295]"),
    ({"seed": 10 ** 400}, "seed", "at most"),
    ({"gcs": "127.0.0.1:99999"}, "gcs", "port in 1..65535"),
    ({"gcs": "127.0.0.1:0"}, "gcs", "port in 1..65535"),
    ({"robots": [{"id": 1, "start": [9.0, 0.0, 0.0]}]}, "robots[0].start", "inside the 10 x 10 m arena"),
    ({"robots": [{"id": 1, "start": [0.0, 0.0, 1e300]}]}, "robots[0].start[2]", "a number in [-7, 7], got 1e+300"),
    ({"scenario": {"type": "formation", "positions": [[0, 1.5], [1.5, 0], [0, -1.5], [50, 0]]}},
     "scenario.positions[3]", "inside the 10 x 10 m arena"),
    ({"scenario": {"type": "mission", "tasks": [{"x": 0, "y": 0}, {"x": 1e6, "y": 0}]}},
     "scenario.tasks[1]", "inside the 10 x 10 m arena"),
])
def test_impossible_fleets_name_the_key(tmp_path, change, key, expected):
    path = _fleet(tmp_path, **change)
    msg = _one_config_error(path, FC.load_fleet)
    assert msg.startswith(f"{path}: {key}: expected") and expected in msg, msg


def test_a_fleet_names_its_broken_robot_template(tmp_path):
    template = _write(tmp_path, "robot: [1, 2\n", "template.yaml")
    path = _fleet(tmp_path, robot=str(template))
    from sitl.launcher import build
    with pytest.raises(ConfigError) as info:
        build(path, tmp_path / "run")
    assert str(info.value) == f"{template}: line 2: expected valid YAML"


def test_a_world_too_large_for_its_grid_names_size_and_resolution(tmp_path):
    path = _write(tmp_path, {"size": [1000.0, 1000.0], "resolution": 0.005}, "world.yaml")
    msg = _one_config_error(path, C.load_world)
    assert msg.startswith(f"{path}: size, resolution: expected at most") and "200000 x 200000 cells" in msg
    assert C.load_world(_write(tmp_path, {"size": [100.0, 100.0], "resolution": 0.05}, "ok.yaml")).size == (100, 100)
    msg = _one_config_error(_write(tmp_path, {"size": [-1.0, 5.0]}, "neg.yaml"), C.load_world)
    assert "size[0]: expected a number in [0.01, 100000]" in msg


@pytest.mark.parametrize("obstacle, key, expected", [
    ({"center": [0, 0], "size": [-1, -1]}, "obstacles[0].size[0]", "a number in (0, 100000], got -1.0"),
    ({"center": [0, 0], "size": [0, 0]}, "obstacles[0].size[0]", "a number in (0, 100000], got 0.0"),
    ({"center": [0, 0], "size": [1, 0]}, "obstacles[0].size[1]", "a number in (0, 100000], got 0.0"),
    ({"center": [1e9, 1e9], "size": [1, 1]}, "obstacles[0].center[0]", "a number in [-50000, 50000], got 1000000000.0"),
    ({"center": [7, 0], "size": [1, 1]}, "obstacles[0].center",
     "a point inside the 10 x 10 m arena of {path} (|x| < 5, |y| < 5), got (7.0, 0.0)"),
])
def test_a_world_obstacle_that_cannot_be_is_refused_naming_it(tmp_path, capsys, obstacle, key, expected):
    """In the world file, and from `mrta daemon --check` of a robot whose map it is (exit 2, one line)."""
    from runtime.cli import main
    path = _write(tmp_path, {"size": [10.0, 10.0], "obstacles": [{"center": [1, 1], "size": [1, 1]}, obstacle]},
                  "map.yaml")
    msg = _one_config_error(path, C.load_world)
    key = key.replace("obstacles[0]", "obstacles[1]")
    assert msg == f"{path}: {key}: expected {expected.format(path=path)}"
    assert main(["daemon", str(_robot(tmp_path, planning={"map": "map.yaml"})), "--check"]) == 2
    assert capsys.readouterr().err == f"mrta: {msg}\n"


# --------------------------------------------------------------------------- what start-up checks (daemon --check)

def _robot(tmp_path, **sections):
    data = {"robot": {"id": 1}, "base": {"port": "loop://"}, "gps": {"port": "loop://"},
            "comms": {"listen": "127.0.0.1:14601", "gcs": "127.0.0.1:14550", "peers": []}}
    for k, v in sections.items():
        data[k] = {**data.get(k, {}), **v}
    return _write(tmp_path, data)


@pytest.mark.parametrize("sections, key, expected", [
    ({"comms": {"listen": "nohost"}}, "comms.listen", "host:port"),
    ({"comms": {"listen": "127.0.0.1:99999"}}, "comms.listen", "port in 1..65535"),
    ({"comms": {"gcs": "127.0.0.1:99999"}}, "comms.gcs", "port in 1..65535"),
    ({"comms": {"gcs": "224.0.0.1:14550"}}, "comms.gcs", "a unicast address"),
    ({"comms": {"peers": [{"id": 2, "address": "no.such.host.invalid:14602"}]}}, "comms.peers[0].address",
     "an address that resolves"),
    ({"comms": {"peers": [{"id": 1, "address": "127.0.0.1:14602"}]}}, "comms.peers[0].id", "another robot's id"),
    ({"comms": {"peers": [{"id": 2, "address": "127.0.0.1:14602"}, {"id": 2, "address": "127.0.0.1:14603"}]}},
     "comms.peers[1].id", "a peer id listed once"),
    ({"planning": {"map": "nowhere.yaml"}}, "planning.map", "a world YAML file"),
    ({"comms": {"signing_key": "/nonexistent/fleet.key"}}, "comms.signing_key", "signing key file not found"),
    ({"base": {"baudrate": -1}}, "base", "baud rate -1: expected one of"),
    ({"base": {"baudrate": 12345}}, "base", "baud rate 12345"),
    ({"planning": {"map": "map.yaml"}, "localization": {"initial_pose": [6.0, 0.0, 0.0]}},
     "localization.initial_pose", "a point inside the 10 x 10 m arena of"),
    ({"localization": {"initial_pose": [1e300, 1e300, 0]}}, "localization.initial_pose[0]",
     "expected a number in [-50000, 50000], got 1e+300"),
])
def test_check_runs_every_start_up_check(tmp_path, capsys, sections, key, expected):
    """`mrta daemon CONFIG --check` refuses what the daemon would refuse, in one line naming file and key."""
    from runtime.cli import main
    _write(tmp_path, {"size": [10.0, 10.0]}, "map.yaml")
    path = _robot(tmp_path, **sections)
    assert main(["daemon", str(path), "--check"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"mrta: {path}: {key}: ") and expected in err, err


def test_check_says_ok_for_a_config_the_daemon_takes(tmp_path, capsys):
    from runtime.cli import main
    world = _write(tmp_path, {"size": [10.0, 10.0]}, "map.yaml")
    key = tmp_path / "fleet.key"
    key.write_text("ab" * 32)
    path = _robot(tmp_path, planning={"map": "map.yaml"}, comms={"signing_key": str(key), "peers": [
        {"id": 2, "address": "localhost:14602"}, {"id": 3, "address": "[::1]:14603"}]})
    assert world.exists()
    assert main(["daemon", str(path), "--check"]) == 0
    assert capsys.readouterr().out.startswith(f"{path}: ok (robot 1")


def test_building_the_cli_loads_no_simulator():
    """`mrta daemon --check` and every other command build the whole CLI, experiments included: none of them
    may import pybullet (its banner on stderr breaks the one-line error, and a robot has no use for it)."""
    code = "from runtime.cli import main"
    proc = subprocess.run([sys.executable, "-c", code + "; main(['experiment', '--help'])"], cwd=ROOT, timeout=60,
                          capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert "pybullet build time" not in proc.stderr + proc.stdout, proc.stderr[-300:]


def test_a_fleet_signing_key_is_found_beside_the_fleet_file_whatever_the_working_folder(tmp_path, monkeypatch):
    """``signing_key`` resolves against the fleet file, as ``world`` and ``robot`` do; a missing one names the key."""
    (tmp_path / "keys").mkdir()
    (tmp_path / "keys" / "fleet.key").write_text("ab" * 32 + "\n")
    data = dict(yaml.safe_load((CONFIGS / "fleets" / "create2_4.yaml").read_text()),
                world=str(CONFIGS / "worlds" / "arena_10m.yaml"), robot=str(CONFIGS / "robots" / "create2.yaml"),
                signing_key="keys/fleet.key")
    path = _write(tmp_path, data, "fleet.yaml")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert Path(FC.load_fleet(path).signing_key).resolve() == (tmp_path / "keys" / "fleet.key").resolve()
    path = _write(tmp_path, dict(data, signing_key="keys/none.key"), "fleet.yaml")
    with pytest.raises(ConfigError, match=r"fleet.yaml: signing_key: expected a path to an existing file relative"):
        FC.load_fleet(path)
    (tmp_path / "keys" / "bad.key").write_text("abc\n")                 # there, but no key: the line names both files
    path = _write(tmp_path, dict(data, signing_key="keys/bad.key"), "fleet.yaml")
    with pytest.raises(InputError) as info:
        FC.load_fleet(path)
    assert str(info.value) == (f"{path}: signing_key {tmp_path / 'keys' / 'bad.key'}: expected "
                               "64 hex characters (a 32-byte MAVLink signing key), got 3 characters")
