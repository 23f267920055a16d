"""Fuzz every input a person hands the runtime (issue 14, items 6 and 9): config files of every kind, JSON problems
and command-line argument vectors, random, truncated and bit-flipped, with hostile YAML (alias bombs, deep nesting,
huge integers) mixed in.

Whatever the input, the outcome is one of: it loads (a config) or the command finishes (exit 0 or 1), or it is
refused with exactly one line -- ``InputError`` naming the file, or exit 2 with one line ``mrta: ...`` on stderr --
never another exception, and within :data:`TIME_BOUND` seconds.  No fleet runs: `mrta sitl run` stops where it
would build the world and `mrta daemon` is always given ``--check``; no name is looked up on a network.
"""
from __future__ import annotations

import json
import socket
import time
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, event, given, settings, strategies as st

from runtime import cli
from runtime import config as C
from runtime.errors import InputError
from sitl import fleet_config as FC

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"
TIME_BOUND = 30.0       # s per example: a hang guard (the slowest seen is ~0.3 s), not a timing assert
FUZZ = settings(max_examples=200, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


class Started(Exception):
    """A command got past every check and began its work (a world or a daemon would be built now)."""


@pytest.fixture
def no_network(monkeypatch):
    """Addresses resolve only when numeric (or localhost): a mutated host name never reaches a name server."""
    real = socket.getaddrinfo

    def numeric_only(host, port, family=0, type=0, proto=0, flags=0):
        if host != "localhost":
            flags |= socket.AI_NUMERICHOST
        return real(host, port, family, type, proto, flags)

    monkeypatch.setattr(socket, "getaddrinfo", numeric_only)


@pytest.fixture
def no_work(monkeypatch):
    """`mrta sitl run` and `mrta daemon` stop where their real work would begin."""
    def started(*args, **kwargs):
        raise Started

    monkeypatch.setattr("sitl.launcher.build", started)
    monkeypatch.setattr("runtime.daemon.Daemon", started)


# --------------------------------------------------------------------------- inputs

def mutations(base: bytes) -> st.SearchStrategy[bytes]:
    """``base`` truncated, with bits flipped, or with junk inserted."""
    def flip(bits):
        out = bytearray(base)
        for b in bits:
            out[b // 8] ^= 1 << (b % 8)
        return bytes(out)

    return st.one_of(
        st.integers(0, len(base)).map(lambda k: base[:k]),
        st.lists(st.integers(0, 8 * len(base) - 1), min_size=1, max_size=8).map(flip),
        st.tuples(st.integers(0, len(base)), st.binary(min_size=1, max_size=12)).map(
            lambda a: base[:a[0]] + a[1] + base[a[0]:]),
    )


def alias_bomb(depth: int, width: int) -> str:
    def level(i):
        if i == 0:
            return "&a0 [" + ",".join(["1"] * width) + "]"
        return f"&a{i} [" + level(i - 1) + "".join(f",*a{i - 1}" for _ in range(width - 1)) + "]"
    return level(depth)


HOSTILE = st.one_of(
    st.builds(alias_bomb, st.integers(1, 9), st.integers(1, 12)),
    st.integers(1, 400).map(lambda k: "[" * k + "]" * k),
    st.integers(1, 200).map(lambda k: "{a: " * k + "1" + "}" * k),
    st.integers(1, 5000).map(lambda k: "1" + "0" * k),
    st.sampled_from(["1e400", "-1e400", ".nan", ".inf", "&r [*r]", "2020-13-45", "0x" + "f" * 900, "!!binary AAAA",
                     "!!set {a, b}", "<<: {x: 1}", "*undefined", "? [a, b]\n  : 1", "1:2:3:4:5:6:7:8:9:10"]),
)
YAML_SCALARS = st.none() | st.booleans() | st.integers(-10**9, 10**9) | st.floats() | st.text(max_size=8)
YAML_VALUES = st.recursive(YAML_SCALARS, lambda kids: st.lists(kids, max_size=4)
                           | st.dictionaries(st.text(max_size=8), kids, max_size=4), max_leaves=12)


def yaml_documents(base: bytes) -> st.SearchStrategy[bytes]:
    """Mutations of ``base``, a hostile value or random data at one of its keys, or random YAML."""
    data = yaml.safe_load(base)
    paths = [(k,) for k in data] + [(k, j) for k, v in data.items() if isinstance(v, dict) for j in v]

    def put_text(path, text):
        indent = "\n" + "  " * len(path)
        head = "".join("  " * i + f"{k}:\n" for i, k in enumerate(path[:-1]))
        return (base.decode() + "\n" + head + "  " * (len(path) - 1) + f"{path[-1]}: "
                + text.replace("\n", indent) + "\n").encode()

    def put_value(path, value):
        doc = json.loads(json.dumps(data))
        node = doc
        for k in path[:-1]:
            node = node[k]
        node[path[-1]] = value
        return yaml.safe_dump(doc).encode()

    return st.one_of(
        mutations(base),
        st.builds(put_text, st.sampled_from(paths), HOSTILE),
        st.builds(put_value, st.sampled_from(paths), YAML_VALUES),
        YAML_VALUES.map(lambda v: yaml.safe_dump(v).encode()),
    )


def timed(fn, *args):
    t0 = time.monotonic()
    try:
        return fn(*args)
    finally:
        assert time.monotonic() - t0 < TIME_BOUND, f"{fn.__name__} took {time.monotonic() - t0:.1f} s"


def refused_in_one_line(fn, *args, where: Path) -> None:
    """``fn(*args)`` returns, or raises InputError in one line naming a file under ``where``."""
    try:
        timed(fn, *args)
    except InputError as exc:
        msg = str(exc)
        assert "\n" not in msg and msg.startswith(str(where)), msg
        event("refused: " + msg[len(str(where)):].split(": expected")[-1].split(", got")[0][:30])
    else:
        event("loaded")


def exits_cleanly(capsys, argv) -> int:
    """`mrta ARGV` ends with 0 or 1, or 2 with exactly one stderr line ``mrta: ...``; never a traceback."""
    capsys.readouterr()
    try:
        code = timed(cli.main, argv)
    except SystemExit as exc:            # argparse
        code = exc.code
    err = capsys.readouterr().err
    assert code in (0, 1, 2), (argv, code)
    event(f"exit {code}")
    if code == 2:
        assert err.count("\n") == 1 and err.startswith("mrta: "), (argv, err)
    return code


# --------------------------------------------------------------------------- config files

def _robot_files(tmp: Path) -> bytes:
    (tmp / "map.yaml").write_bytes((CONFIGS / "worlds" / "boxes_10m.yaml").read_bytes())
    (tmp / "fleet.key").write_text("0f" * 32 + "\n")
    data = yaml.safe_load((CONFIGS / "robots" / "create2.yaml").read_text())
    data["base"]["port"] = data["gps"]["port"] = "loop://"
    data["comms"].update(peers=[{"id": 2, "address": "127.0.0.1:14602"}], signing_key=str(tmp / "fleet.key"))
    data["planning"] = {"map": "map.yaml", "planner": "astar"}
    return yaml.safe_dump(data, sort_keys=False).encode()


def _fleet_files(tmp: Path, name: str) -> bytes:
    """A shipped fleet with its world and robot template copied beside it."""
    (tmp / "world.yaml").write_bytes((CONFIGS / "worlds" / "boxes_10m.yaml").read_bytes())
    data = yaml.safe_load((CONFIGS / "fleets" / name).read_text())
    (tmp / "robot.yaml").write_bytes((CONFIGS / "fleets" / data["robot"]).resolve().read_bytes())
    data.update(world="world.yaml", robot="robot.yaml")
    return yaml.safe_dump(data, sort_keys=False).encode()


def _load_robot_and_check(path):
    C.validate_robot(C.load_robot(path))


def _load_fleet_and_templates(path):
    fleet = FC.load_fleet(path)
    for r in fleet.robots:
        C.load_robot(fleet.template(r.id))


@FUZZ
@given(data=st.data())
def test_robot_configs(tmp_path, no_network, data):
    doc = data.draw(yaml_documents(_robot_files(tmp_path)))
    (tmp_path / "robot.yaml").write_bytes(doc)
    refused_in_one_line(_load_robot_and_check, tmp_path / "robot.yaml", where=tmp_path)


@FUZZ
@given(doc=yaml_documents((CONFIGS / "worlds" / "boxes_10m.yaml").read_bytes()))
def test_world_configs(tmp_path, doc):
    (tmp_path / "world.yaml").write_bytes(doc)
    refused_in_one_line(C.load_world, tmp_path / "world.yaml", where=tmp_path)


@FUZZ
@given(data=st.data(), name=st.sampled_from(["create2_4.yaml", "coalition_6.yaml", "operator_4.yaml"]))
def test_fleet_configs_with_their_scenarios_and_templates(tmp_path, data, name):
    doc = data.draw(yaml_documents(_fleet_files(tmp_path, name)))
    which = data.draw(st.sampled_from(["fleet.yaml", "robot.yaml"]))     # the fleet, or its robot template
    (tmp_path / "fleet.yaml").write_bytes(doc if which == "fleet.yaml" else _fleet_files(tmp_path, name))
    if which == "robot.yaml":
        (tmp_path / "robot.yaml").write_bytes(data.draw(yaml_documents((tmp_path / "robot.yaml").read_bytes())))
    refused_in_one_line(_load_fleet_and_templates, tmp_path / "fleet.yaml", where=tmp_path)


# --------------------------------------------------------------------------- JSON problems

JSON_NUMBERS = (st.integers(-10, 10) | st.floats(allow_nan=True, allow_infinity=True)
                | st.sampled_from([10 ** 400, 1.7e308, -1e308, 2 ** 63, 0, 250, 251]))
ASSIGN_GOOD = json.dumps({"costs": [[4, 1, 3], [2, 0, 5], [3, 2, 2]]}).encode()
ASSIGN_POINTS = json.dumps({"robots": [[0, 0], [1, 2]], "tasks": [[3, 1], [-1, 0.5]]}).encode()
WDP_GOOD = json.dumps({"robots": [1, 2, 3], "tasks": ["a", "b"], "bids": [
    {"task": "a", "robots": [1, 2], "value": 3}, {"task": "b", "robots": [3], "value": 2.5},
    {"task": "b", "robots": [2, 3], "value": 4}]}).encode()


def json_documents(good: list[bytes], keys: list[str]) -> st.SearchStrategy[bytes]:
    leaves = JSON_NUMBERS | st.none() | st.booleans() | st.text(max_size=4)
    values = st.recursive(leaves, lambda kids: st.lists(kids, max_size=5)
                          | st.dictionaries(st.sampled_from(keys), kids, max_size=4), max_leaves=25)
    return st.one_of(*(mutations(g) for g in good), values.map(lambda v: json.dumps(v).encode()),
                     st.binary(max_size=40))


@FUZZ
@given(doc=json_documents([ASSIGN_GOOD, ASSIGN_POINTS], ["costs", "robots", "tasks", "world"]),
       method=st.sampled_from(["auction", "bs", "rtma", "hungarian"]))
def test_assign_problems(tmp_path, capsys, doc, method):
    (tmp_path / "p.json").write_bytes(doc)
    exits_cleanly(capsys, ["assign", str(tmp_path / "p.json"), "--method", method, "--json"])


@FUZZ
@given(doc=json_documents([WDP_GOOD], ["robots", "tasks", "bids", "task", "value"]),
       method=st.sampled_from(["auto", "idastar", "bfs", "dp", "sparse", "assignment", "milp"]))
def test_wdp_problems(tmp_path, capsys, doc, method):
    (tmp_path / "b.json").write_bytes(doc)
    exits_cleanly(capsys, ["wdp", str(tmp_path / "b.json"), "--method", method, "--time-limit", "1"])


# --------------------------------------------------------------------------- argument vectors

NUMBERS = st.sampled_from(["nan", "inf", "-inf", "-1", "0", "-0", "0.05", "0.1", "1", "2.5", "100", "101", "400",
                           "401", "36000", "36001", "1e309", "4294967295", "4294967296", "1" + "0" * 400, "abc",
                           "", "0x10", "1_0", " 3"])


def paths(tmp: Path) -> st.SearchStrategy[str]:
    return st.sampled_from([str(tmp / "out.json"), str(tmp / "new" / "deeper" / "out.json"), str(tmp),
                            "/dev/null/x", "/dev/null", str(tmp / "missing" / "f"), "", "a\nb", str(tmp / "ok")])


def vectors(options: dict[str, st.SearchStrategy[str] | None], junk=True) -> st.SearchStrategy[list[str]]:
    """Random option vectors: each option with a value from its strategy (None: a flag), in any order."""
    one = st.sampled_from(sorted(options)).flatmap(
        lambda o: st.just([o]) if options[o] is None else options[o].map(lambda v: [o, v]))
    parts = one | (st.text(max_size=6).map(lambda t: [t]) if junk else one)
    return st.lists(parts, max_size=6).map(lambda ps: [x for p in ps for x in p])


@FUZZ
@given(data=st.data())
def test_sitl_run_arguments(tmp_path, capsys, no_work, data):
    fleet = tmp_path / "fleet.yaml"
    fleet.write_bytes(_fleet_files(tmp_path, "create2_4.yaml"))
    target = data.draw(st.sampled_from([str(fleet), str(tmp_path / "none.yaml"), str(tmp_path / "world.yaml")]))
    argv = ["sitl", "run", target] + data.draw(vectors({
        "--speedup": NUMBERS, "--timeout": NUMBERS, "--seed": NUMBERS, "--instance": NUMBERS,
        "--run-dir": paths(tmp_path), "--manifest": paths(tmp_path), "--json": paths(tmp_path),
        "--method": st.sampled_from(["auction", "bs", "coalition", "greedy"]), "--lockstep": None,
        "--devices-only": None, "--no-signing": None, "--keep-key": None}))
    try:
        exits_cleanly(capsys, argv)
    except Started:                      # every check passed: the values the run would get are sane
        args = cli.build_parser().parse_args(argv)
        assert args.speedup is None or 0.1 <= args.speedup <= 100
        assert args.timeout is None or 1 <= args.timeout <= 36000
        assert args.seed is None or 0 <= args.seed < 2 ** 32
        assert 0 <= args.instance <= 400


@FUZZ
@given(data=st.data())
def test_daemon_check_arguments(tmp_path, capsys, no_work, no_network, data):
    (tmp_path / "robot.yaml").write_bytes(_robot_files(tmp_path))
    (tmp_path / "broken.yaml").write_text("robot: [1, 2\n")
    target = data.draw(st.sampled_from(["robot.yaml", "broken.yaml", "none.yaml", "map.yaml"]))
    argv = ["daemon", str(tmp_path / target), "--check"] + data.draw(vectors({
        "--speedup": NUMBERS, "--epoch": NUMBERS, "--duration": NUMBERS, "--stats": paths(tmp_path),
        "--clock-file": paths(tmp_path)}))
    exits_cleanly(capsys, argv)


@FUZZ
@given(data=st.data())
def test_assign_and_wdp_arguments(tmp_path, capsys, data):
    (tmp_path / "p.json").write_bytes(ASSIGN_GOOD)
    (tmp_path / "b.json").write_bytes(WDP_GOOD)
    if data.draw(st.booleans()):
        argv = ["assign", str(tmp_path / "p.json")] + data.draw(vectors({
            "--method": st.sampled_from(["auction", "bs", "rtma", "hungarian", "x"]), "--bid-timeout": NUMBERS,
            "--json": None}))
    else:
        argv = ["wdp", data.draw(st.sampled_from([str(tmp_path / "b.json"), str(tmp_path / "p.json"), "-"]))] \
            + data.draw(vectors({"--method": st.sampled_from(["auto", "dp", "milp", "bfs", "x"]),
                                 "--node-limit": NUMBERS, "--time-limit": NUMBERS, "--json": None}))
    exits_cleanly(capsys, argv)
