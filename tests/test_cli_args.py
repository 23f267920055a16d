"""Command-line options are checked before a command starts its work: a wrong one is exit 2 with one line naming
it (issue 14, item 6).  `mrta sitl run` and `mrta daemon` never get as far as building a world or a daemon here:
those are replaced by a stand-in that says how far the command got."""
from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from runtime import cli

ROOT = Path(__file__).resolve().parents[1]
FLEET = ROOT / "configs" / "fleets" / "create2_4.yaml"


class Started(Exception):
    """The command got past its checks and began its work."""


@pytest.fixture
def no_fleet(monkeypatch):
    """`mrta sitl run` stops where it would build the world; the arguments it would have built with are kept."""
    seen = {}

    def build(*args, **kwargs):
        seen["args"] = args
        raise Started

    monkeypatch.setattr("sitl.launcher.build", build)
    return seen


@pytest.fixture
def no_daemon(monkeypatch):
    def daemon(cfg, **kwargs):
        raise Started

    monkeypatch.setattr("runtime.daemon.Daemon", daemon)


def one_line_exit_2(capsys, argv) -> str:
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("mrta: "), err
    return err


def _robot(tmp_path) -> Path:
    p = tmp_path / "robot.yaml"
    p.write_text(yaml.safe_dump({"base": {"port": "loop://"}, "gps": {"port": "loop://"},
                                 "comms": {"listen": "127.0.0.1:14601", "gcs": None}}))
    return p


@pytest.mark.parametrize("option, value, expected", [
    ("--speedup", "nan", "--speedup: expected a number in [0.1, 100], got nan"),
    ("--speedup", "inf", "--speedup: expected a number in [0.1, 100], got inf"),
    ("--speedup", "-1", "--speedup: expected a number in [0.1, 100], got -1.0"),
    ("--speedup", "0", "--speedup: expected a number in [0.1, 100], got 0.0"),
    ("--seed", "-1", "--seed: expected a number in [0, 4294967295], got -1"),
    ("--timeout", "0", "--timeout: expected a number in [1, 36000], got 0.0"),
    ("--timeout", "-5", "--timeout: expected a number in [1, 36000], got -5.0"),
    ("--timeout", "nan", "--timeout: expected a number in [1, 36000], got nan"),
    ("--instance", "-1", "--instance: expected a number in [0, 400], got -1"),
    ("--peer-loss", "1.5", "--peer-loss: expected a number in [0, 1], got 1.5"),
    ("--peer-loss", "nan", "--peer-loss: expected a number in [0, 1], got nan"),
    ("--loss-burst", "-1", "--loss-burst: expected a number in [0, 3600], got -1.0"),
    ("--run-dir", "/dev/null/run", "--run-dir /dev/null/run: expected a path whose folders can be made"),
    ("--manifest", "/dev/null/m.json", "--manifest /dev/null/m.json: expected a path whose folders can be made"),
    ("--json", "/dev/null/r.json", "--json /dev/null/r.json: expected a file in an existing folder"),
    ("--json", "{tmp}/missing/r.json", "--json {tmp}/missing/r.json: expected a file in an existing folder"),
    ("--json", "{tmp}", "--json {tmp}: expected a file name, got a folder"),
])
def test_sitl_run_refuses_bad_options_before_building(tmp_path, capsys, no_fleet, option, value, expected):
    value, expected = value.format(tmp=tmp_path), expected.format(tmp=tmp_path)
    err = one_line_exit_2(capsys, ["sitl", "run", str(FLEET), option, value])
    assert err.startswith(f"mrta: {expected}"), err
    assert "args" not in no_fleet


def test_sitl_run_refuses_an_instance_whose_ports_pass_65535(tmp_path, capsys, no_fleet):
    data = yaml.safe_load(FLEET.read_text())
    data.update(world=str(ROOT / "configs" / "worlds" / "arena_10m.yaml"),
                robot=str(ROOT / "configs" / "robots" / "create2.yaml"), base_port=65000)
    fleet = tmp_path / "fleet.yaml"
    fleet.write_text(yaml.safe_dump(data))
    err = one_line_exit_2(capsys, ["sitl", "run", str(fleet), "--instance", "6"])
    assert "--instance: expected an instance whose ports stay <= 65535" in err and "65604" in err
    with pytest.raises(Started):
        cli.main(["sitl", "run", str(fleet), "--instance", "5"])


def test_sitl_run_takes_good_options_as_they_are(tmp_path, no_fleet):
    """Valid options reach the build unchanged (--speedup 0 is refused, not replaced by the fleet's)."""
    run_dir = tmp_path / "new" / "run"
    with pytest.raises(Started):
        cli.main(["sitl", "run", str(FLEET), "--speedup", "0.1", "--seed", "0", "--timeout", "1", "--run-dir",
                  str(run_dir), "--manifest", str(tmp_path / "a" / "b" / "m.json"), "--json", str(tmp_path / "r.json"),
                  "--peer-loss", "0.1", "--loss-burst", "2"])
    fleet, rd, manifest, seed, signing, method, speedup, instance, peer_loss, loss_burst, key, unsigned = no_fleet["args"]
    assert (rd, seed, speedup, instance, peer_loss, loss_burst, key, unsigned) == (str(run_dir), 0, 0.1, 0, 0.1, 2.0,
                                                                                   None, None)
    assert not list(tmp_path.iterdir())           # checked, not made (nor left a probe behind)


@pytest.mark.parametrize("content, expected", [
    (None, "--key {key}: signing key file not found"),
    ("abc\n", "--key {key}: expected 64 hex characters (a 32-byte MAVLink signing key), got 3 characters"),
    ("zz" * 32, "--key {key}: expected 64 hex characters (a 32-byte MAVLink signing key), got a non-hex character"),
])
def test_sitl_run_refuses_a_key_file_that_is_missing_or_no_key(tmp_path, capsys, no_fleet, content, expected):
    key = tmp_path / "fleet.key"
    if content is not None:
        key.write_text(content)
    err = one_line_exit_2(capsys, ["sitl", "run", str(FLEET), "--key", str(key)])
    assert err == f"mrta: {expected.format(key=key)}\n"
    assert "args" not in no_fleet


def test_sitl_run_takes_a_key_file_for_a_signed_fleet_only(tmp_path, capsys, no_fleet):
    key = tmp_path / "fleet.key"
    key.write_text("ab" * 32 + "\n")
    err = one_line_exit_2(capsys, ["sitl", "run", str(FLEET), "--key", str(key), "--no-signing"])
    assert err == "mrta: --key: expected a signed fleet, got --no-signing as well\n"
    with pytest.raises(Started):
        cli.main(["sitl", "run", str(FLEET), "--key", str(key)])
    assert no_fleet["args"][-2] == str(key)


def test_argument_errors_are_one_line(capsys):
    with pytest.raises(SystemExit) as info:
        cli.main(["sitl", "run", str(FLEET), "--speedup", "fast"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err == "mrta: sitl run: argument --speedup: invalid float value: 'fast' (see mrta sitl run --help)\n"
    with pytest.raises(SystemExit):
        cli.main(["wdp", "a.json", "b\nc"])
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "b\\nc" in err


@pytest.mark.parametrize("options, expected", [
    (["--stats", "{tmp}/missing/s.json"], "--stats {tmp}/missing/s.json: expected a file in an existing folder"),
    (["--clock-file", "{tmp}/missing/clock"], "--clock-file {tmp}/missing/clock: expected a file in an existing"),
    (["--speedup", "nan"], "--speedup: expected a number > 0, got nan"),
    (["--speedup", "0"], "--speedup: expected a number > 0, got 0.0"),
    (["--duration", "-1"], "--duration: expected a number > 0, got -1.0"),
    (["--epoch", "inf"], "--epoch: expected a finite number, got inf"),
])
def test_daemon_refuses_bad_options_before_starting(tmp_path, capsys, no_daemon, options, expected):
    options = [o.format(tmp=tmp_path) for o in options]
    err = one_line_exit_2(capsys, ["daemon", str(_robot(tmp_path)), *options])
    assert err.startswith(f"mrta: {expected.format(tmp=tmp_path)}"), err


def test_daemon_with_good_options_starts(tmp_path, no_daemon):
    with pytest.raises(Started):
        cli.main(["daemon", str(_robot(tmp_path)), "--stats", str(tmp_path / "s.json"), "--speedup", "2",
                  "--duration", "1"])


def test_the_clock_barrier_names_a_folder_that_vanished(tmp_path):
    from runtime.config import ConfigError
    from runtime.daemon_cli import _wait_for_clock
    with pytest.raises(ConfigError, match=r"clock: expected a folder to write clock.ready.3 in"):
        _wait_for_clock(str(tmp_path / "gone" / "clock"), 3, timeout=0.1)


def test_argcheck_numbers():
    from runtime import argcheck
    from runtime.errors import InputError
    argcheck.number(None, "--x", 0, 1)
    argcheck.number(1, "--x", 0, 1)
    for bad in (math.nan, math.inf, -math.inf, 2.0, -0.5):
        with pytest.raises(InputError):
            argcheck.number(bad, "--x", 0, 1)
    with pytest.raises(InputError, match=r"--x: expected a number > 0, got 0"):
        argcheck.number(0, "--x", 0, lo_open=True)
    with pytest.raises(InputError, match=r"--n: expected a number in \[0, 400\], got an integer of 401 digits"):
        argcheck.number(10 ** 400, "--n", 0, 400)          # found by the fuzz suite: was an OverflowError


def test_no_signing_wins_over_the_fleets_signing_key(tmp_path):
    """A fleet file naming a signing_key, run with --no-signing: the robots do not sign (the command line wins), as
    --no-signing's help says; without it they sign with that key."""
    import yaml
    from runtime.comms.link import new_key
    from sitl import fleet_config as FC
    from sitl.launcher import fleet_key
    key = new_key(tmp_path / "site.key")
    data = yaml.safe_load(FLEET.read_text())
    for k in ("world", "robot"):
        data[k] = str((FLEET.parent / data[k]).resolve())
    data["signing_key"] = str(key)
    path = tmp_path / "fleet.yaml"
    path.write_text(yaml.safe_dump(data))
    fleet = FC.load_fleet(path)
    assert fleet_key(fleet, None, False, tmp_path) == (None, False)
    assert fleet_key(fleet, None, True, tmp_path) == (key.resolve(), False)
