"""The robot deployment kit (runtime/deploy, docs/deploy.md): `mrta init-robot`, the systemd unit checked by
`systemd-analyze verify`, the udev rules checked against udev's grammar, and the daemon run the way the unit runs
it: as a user with no home and an unwritable HOME, stopped by SIGTERM."""
from __future__ import annotations

import os
import pwd
import re
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest
import yaml
from hypothesis import given, settings, strategies as st

from runtime.cli import main
from runtime.config.robot import load_robot
from runtime.deploy import init_robot as D

ROOT = Path(__file__).resolve().parents[1]


# --------------------------------------------------------------------------- mrta init-robot

@pytest.mark.parametrize("base", list(D.BASES))
def test_init_robot_writes_a_config_the_daemon_accepts_a_key_and_a_readme(tmp_path, base, capsys):
    where = tmp_path / "etc" / "mrta"
    assert main(["init-robot", str(where), "--base", base, "--id", "7", "--peer", "8=127.0.0.1:14602"]) == 0
    assert sorted(p.name for p in where.iterdir()) == ["README.md", "fleet.key", "robot.yaml"]
    key = where / "fleet.key"
    assert stat.S_IMODE(key.stat().st_mode) == 0o600 and re.fullmatch(r"[0-9a-f]{64}\n", key.read_text())
    cfg = load_robot(where / "robot.yaml")
    assert (cfg.robot.id, cfg.comms.listen, cfg.comms.signing_key) == (7, "0.0.0.0:14601", str(key))
    assert [(p.id, p.address) for p in cfg.comms.peers] == [(8, "127.0.0.1:14602")]
    rules = D.RULES.read_text()
    assert f'SYMLINK+="{cfg.gps.port.removeprefix("/dev/")}"' in rules
    if base == "can":
        assert (cfg.base.interface, cfg.base.channel) == ("socketcan", "can0")
    else:                                          # the base's port is a name the udev rules give
        assert f'SYMLINK+="{cfg.base.port.removeprefix("/dev/")}"' in rules
    assert main(["daemon", str(where / "robot.yaml"), "--check"]) == 0
    assert "systemctl enable --now mrta-daemon@robot" in (where / "README.md").read_text()


def test_init_robot_copies_a_fleet_key_and_never_overwrites(tmp_path, capsys):
    assert main(["key", str(tmp_path / "fleet.key")]) == 0
    assert main(["init-robot", str(tmp_path / "r2"), "--base", "create2", "--id", "2",
                 "--key", str(tmp_path / "fleet.key")]) == 0
    assert (tmp_path / "r2" / "fleet.key").read_bytes() == (tmp_path / "fleet.key").read_bytes()
    before = {p.name: p.read_bytes() for p in (tmp_path / "r2").iterdir()}
    capsys.readouterr()
    assert main(["init-robot", str(tmp_path / "r2"), "--base", "pioneer"]) == 2
    assert "a file is already there" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in (tmp_path / "r2").iterdir()} == before


@pytest.mark.parametrize("args, expected", [
    (["--id", "0"], "robot.yaml: robot.id: expected a number in [1, 250], got 0"),
    (["--peer", "1=127.0.0.1:14602"], "robot.yaml: comms.peers[0].id: expected another robot's id"),
    (["--peer", "two=127.0.0.1:14602"], "--peer: expected ID=HOST:PORT, got 'two=127.0.0.1:14602'"),
    (["--gcs", "127.0.0.1:0"], "robot.yaml: comms.gcs: expected host:port with port in 1..65535"),
    (["--key", "/nonexistent/fleet.key"], "/nonexistent/fleet.key: signing key file not found"),
])
def test_init_robot_refuses_bad_input_in_one_line_and_writes_nothing(tmp_path, capsys, args, expected):
    assert main(["init-robot", str(tmp_path / "r"), "--base", "create2", *args]) == 2
    err = capsys.readouterr().err
    assert expected in err and err.count("\n") == 1
    assert not (tmp_path / "r").exists()


@settings(max_examples=50)
@given(st.one_of(st.text(max_size=30), st.builds(lambda i, h, p: f"{i}={h}:{p}", st.integers(-5, 300),
                                                 st.text(max_size=8), st.integers(-1, 70000))))
def test_a_peer_argument_is_a_peer_or_one_line(text):
    from runtime.config import ConfigError, from_dict
    from runtime.config.robot import Peer
    from runtime.errors import InputError

    try:
        peer = D._peer(text)
        from_dict(Peer, peer, "robot.yaml")
    except ConfigError as exc:
        assert str(exc).startswith("robot.yaml: ") and "\n" not in str(exc)
    except InputError as exc:
        assert str(exc).startswith("--peer: expected ID=HOST:PORT")
    else:
        rid, _, address = text.partition("=")
        assert (peer["id"], peer["address"]) == (int(rid), address)


def test_init_robot_prints_the_shipped_unit_and_rules(capsys):
    assert main(["init-robot", "--print", "udev"]) == 0
    assert capsys.readouterr().out == D.RULES.read_text()
    assert main(["init-robot", "--print", "unit"]) == 0
    out = capsys.readouterr().out
    assert out == D.unit_text()
    mrta = Path(sys.executable).parent / "mrta"
    if mrta.is_file():                               # ExecStart names the mrta beside this Python
        assert f"\nExecStart={mrta} -v daemon /etc/mrta/%i.yaml" in out


def test_init_robot_without_dir_or_base_says_what_it_needs(capsys):
    assert main(["init-robot", "--base", "create2"]) == 2
    assert "expected DIR and --base" in capsys.readouterr().err


# --------------------------------------------------------------------------- the systemd unit

def _unit_keys(text: str) -> dict[str, list[str]]:
    keys: dict[str, list[str]] = {}
    for line in text.splitlines():
        if line and not line.startswith(("#", "[")):
            k, _, v = line.partition("=")
            keys.setdefault(k, []).append(v)
    return keys


def test_unit_runs_the_daemon_as_a_dedicated_user_and_restarts_it_on_failure():
    keys = _unit_keys(D.UNIT.read_text())
    assert keys["User"] == ["mrta"] and keys["Restart"] == ["on-failure"] and keys["KillSignal"] == ["SIGTERM"]
    assert keys["CacheDirectory"] == ["mrta"] and keys["StateDirectory"] == ["mrta"]
    assert keys["RestartPreventExitStatus"] == ["2"]          # a bad config waits for a person
    assert keys["ExecStart"] == [f"{D.UNIT_MRTA} -v daemon /etc/mrta/%i.yaml --stats ${{STATE_DIRECTORY}}/%i.json"]
    # after any exit the base is told to stop once more (issue 31); "-": an unplugged base does not fail the unit
    assert keys["ExecStopPost"] == [f"-{D.UNIT_MRTA} stop-base /etc/mrta/%i.yaml"]


def _verify(unit_text: str, folder: Path) -> tuple[int, str]:
    path = folder / "mrta-daemon@robot.service"     # an instance: verify refuses a bare template name
    path.write_text(unit_text)
    out = subprocess.run(["systemd-analyze", "verify", str(path)], capture_output=True, text=True, timeout=60)
    return out.returncode, (out.stdout + out.stderr).strip()


@pytest.mark.skipif(shutil.which("systemd-analyze") is None,
                    reason="systemd-analyze is not installed (Debian: apt-get install systemd)")
def test_unit_passes_systemd_analyze_verify(tmp_path):
    mrta = Path(sys.executable).parent / "mrta"
    if not mrta.is_file():
        pytest.skip(f"no mrta script beside {sys.executable}: ExecStart could not name an executable")
    text = D.unit_text(str(mrta))
    assert f"ExecStart={mrta} -v daemon" in text
    assert f"ExecStopPost=-{mrta} stop-base" in text
    assert _verify(text, tmp_path) == (0, "")
    # verify only warns (exit 0) on a key it does not know: the test reads its output, so it can fail
    code, out = _verify(text.replace("Restart=on-failure", "Restart=on-failures"), tmp_path)
    assert "Failed to parse service restart specifier" in out


# --------------------------------------------------------------------------- the udev rules

# udev(7), "Rules files": a rule is one line of comma-separated KEY OPERATOR "VALUE"; match keys take == or !=,
# assignment keys = += -= :=; these keys take {an attribute or variable name}.  Only keys this project may use.
MATCH = {"ACTION", "DEVPATH", "KERNEL", "NAME", "SYMLINK", "SUBSYSTEM", "DRIVER", "ATTR", "KERNELS", "SUBSYSTEMS",
         "DRIVERS", "ATTRS", "ENV", "TAG", "TEST", "PROGRAM", "RESULT"}
ASSIGN = {"NAME", "SYMLINK", "OWNER", "GROUP", "MODE", "ATTR", "ENV", "TAG", "RUN", "LABEL", "GOTO", "OPTIONS"}
BRACED = {"ATTR", "ATTRS", "ENV", "TEST", "RUN"}
PAIR = re.compile(r'\s*([A-Z]+)(?:\{([^{}"]+)\})?\s*(==|!=|\+=|-=|:=|=)\s*"((?:[^"\\]|\\.)*)"\s*')


def parse_rule(line: str) -> list[tuple[str, str | None, str, str]]:
    """One udev rule line as (key, {name}, operator, value) tuples; ValueError saying where it breaks the grammar."""
    pairs, pos = [], 0
    while pos < len(line):
        m = PAIR.match(line, pos)
        if m is None:
            raise ValueError(f"column {pos + 1}: expected KEY OP \"VALUE\"")
        key, name, op, value = m.groups()
        if (key in BRACED) != (name is not None):
            raise ValueError(f"{key}: {'needs' if key in BRACED else 'takes no'} {{name}}")
        if op in ("==", "!=") and key not in MATCH or op not in ("==", "!=") and key not in ASSIGN:
            raise ValueError(f"{key}: operator {op} not allowed")
        pairs.append((key, name, op, value))
        pos = m.end()
        if pos < len(line):
            if line[pos] != ",":
                raise ValueError(f"column {pos + 1}: expected ','")
            pos += 1
    if not pairs:
        raise ValueError("an empty rule")
    return pairs


def _rules(text: str) -> list[list[tuple]]:
    return [parse_rule(line) for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]


def test_udev_rules_follow_udevs_grammar_and_name_each_adapter():
    rules = _rules(D.RULES.read_text())
    names = {}
    for pairs in rules:
        d = {(k, n): (op, v) for k, n, op, v in pairs}
        assert d[("SUBSYSTEM", None)] == ("==", "tty")
        vendor, product = d[("ATTRS", "idVendor")], d[("ATTRS", "idProduct")]
        assert vendor[0] == product[0] == "==" and all(re.fullmatch(r"[0-9a-f]{4}", v[1]) for v in (vendor, product))
        assert d[("GROUP", None)] == ("=", "dialout") and d[("MODE", None)] == ("=", "0660")
        names.setdefault(d[("SYMLINK", None)][1], set()).add(f"{vendor[1]}:{product[1]}")
    assert names == {"mrta-create2": {"0403:6015"}, "mrta-pioneer": {"0403:6001"},
                     "mrta-gps": {"1546:01a7", "1546:01a8", "067b:2303"}}


@pytest.mark.parametrize("line, why", [
    ('SUBSYSTEM=="tty", ATTRS{idVendor}=="0403', "expected KEY OP"),           # an unclosed quote
    ('SUBSYSTEM=="tty" ATTRS{idVendor}=="0403"', "expected ','"),
    ('SUBSYSTEM=="tty", ATTRS{idVendor}="0403"', "operator = not allowed"),    # ATTRS only matches
    ('SUBSYSTEM=="tty", ATTRS=="0403"', "needs {name}"),
    ('SUBSYSTEM=="tty", SYMLNK+="x"', "operator += not allowed"),
    ('SUBSYSTEM=="tty", GROUP=="dialout"', "operator == not allowed"),
])
def test_the_grammar_check_refuses_broken_rules(line, why):
    with pytest.raises(ValueError, match=re.escape(why)):
        parse_rule(line)


@settings(max_examples=25)
@given(st.data())
def test_the_grammar_check_never_fails_otherwise_on_damaged_rules(data):
    line = D.RULES.read_text().splitlines()[12]
    assert line.startswith("SUBSYSTEM")
    cut = data.draw(st.integers(0, len(line)))
    damaged = data.draw(st.sampled_from([line[:cut], line[:cut] + data.draw(st.text(max_size=3)) + line[cut:]]))
    try:
        parse_rule(damaged)
    except ValueError:
        pass


def _udevadm_test(rules: dict[str, str], tmp_path: Path) -> list[str]:
    """What udev's own parser says about ``rules`` (file name -> text): `udevadm test` reads them from
    /run/udev/rules.d, here a tmpfs in a mount namespace of its own, so the machine's rules are untouched."""
    for name, text in rules.items():
        (tmp_path / name).write_text(text)
    script = (f"mount -t tmpfs tmpfs /run/udev/rules.d && cp {tmp_path}/*.rules /run/udev/rules.d/ && "
              "udevadm test --action=add /sys/class/tty/console")
    out = subprocess.run(["unshare", "-m", "sh", "-c", script], capture_output=True, text=True, timeout=60)
    if "Reading rules file: /run/udev/rules.d/" not in out.stdout + out.stderr:
        pytest.skip(f"udevadm test in a private mount namespace did not run here: {out.stderr.strip()[-200:]}")
    return [line for line in (out.stdout + out.stderr).splitlines() if line.startswith("/run/udev/rules.d/")]


@pytest.mark.skipif(os.geteuid() != 0 or not (shutil.which("udevadm") and shutil.which("unshare"))
                    or not Path("/run/udev/rules.d").is_dir() or not Path("/sys/class/tty/console").exists(),
                    reason="needs root, udevadm (Debian: apt-get install udev), unshare and /sys/class/tty/console")
def test_udevs_own_parser_takes_the_rules(tmp_path):
    """udev 252 (Debian 12) has no `udevadm verify` (254); `udevadm test` parses every rules file it reads and names
    the file and line of each rule it cannot take."""
    broken = 'SUBSYSTEM=="tty", ATTRS{idVendor}="0403", SYMLINK+="mrta-x"\nSUBSYSTEM=="tty", SYMLNK+="mrta-y"\n'
    said = _udevadm_test({"99-mrta-serial.rules": D.RULES.read_text(), "98-broken.rules": broken}, tmp_path)
    assert said == ["/run/udev/rules.d/98-broken.rules:1 Invalid operator for ATTRS.",
                    "/run/udev/rules.d/98-broken.rules:2 Invalid key 'SYMLNK'"]


# --------------------------------------------------------------------------- the daemon as the unit runs it

def _service_user():
    """(uid, gid, cleanup) of a throwaway system user without a home when root, else this user."""
    if os.geteuid() != 0 or shutil.which("useradd") is None:
        return os.getuid(), os.getgid(), lambda: None
    name = f"mrtat{os.getpid() % 100000}"
    subprocess.run(["useradd", "--system", "--no-create-home", "--home-dir", "/nonexistent", "--shell",
                    "/usr/sbin/nologin", name], check=True, capture_output=True, timeout=30)
    pw = pwd.getpwnam(name)
    return pw.pw_uid, pw.pw_gid, lambda: subprocess.run(["userdel", name], capture_output=True, timeout=30)


def test_daemon_runs_as_a_user_without_a_home_and_stops_the_base_on_sigterm():
    """What `systemctl start` then `systemctl stop` does to the daemon, as far as this machine allows: a user with no
    home (HOME=/nonexistent, nothing of the environment kept), --check, then a run on a Create whose serial port is
    a pty this test reads, ended by SIGTERM: exit 0 and the OI's stop bytes last on the wire."""
    from runtime.drivers import create_oi_protocol as P
    from sitl.ports import free_udp_base
    from tests.sitl_util import port_block

    uid, gid, cleanup = _service_user()
    folder = Path(tempfile.mkdtemp(prefix="mrta-deploy-"))
    master, slave = os.openpty()
    proc = None
    try:
        os.chmod(folder, 0o755)
        port = free_udp_base(2, port_block())
        D.init_robot(folder / "etc", "create2", gcs=f"127.0.0.1:{port + 1}")
        cfg = folder / "etc" / "robot.yaml"
        data = yaml.safe_load(cfg.read_text())
        data["base"]["port"] = os.ttyname(slave)
        data["gps"]["port"] = "loop://"
        data["comms"]["listen"] = f"127.0.0.1:{port}"
        cfg.write_text(yaml.safe_dump(data))
        state = folder / "state"
        state.mkdir()
        for path in (folder / "etc" / "fleet.key", state, os.ttyname(slave)):
            os.chown(path, uid, gid)
        env = {"HOME": "/nonexistent", "PATH": "/usr/bin:/bin", "PYTHONPATH": str(ROOT), "PYTHONDONTWRITEBYTECODE": "1"}
        run = [sys.executable, "-m", "runtime.cli", "-v", "daemon", str(cfg)]
        if os.geteuid() == 0 and uid != 0:
            run = ["setpriv", f"--reuid={uid}", f"--regid={gid}", "--clear-groups", "--", *run]
        check = subprocess.run([*run, "--check"], env=env, capture_output=True, text=True, timeout=120)
        assert (check.returncode, check.stderr) == (0, "") and check.stdout.endswith("ok (robot 1, base create_oi, "
                                                                                      "allocation auction)\n")
        wire = bytearray()
        reader = threading.Thread(target=_drain, args=(master, wire), daemon=True)
        reader.start()
        proc = subprocess.Popen([*run, "--stats", str(state / "robot.json")], env=env, stderr=subprocess.PIPE,
                                text=True)
        deadline = time.monotonic() + 60
        while not (state / "robot.json").exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert proc.poll() is None, proc.stderr.read()
        assert (state / "robot.json").stat().st_uid == uid
        proc.send_signal(signal.SIGTERM)
        err = proc.communicate(timeout=60)[1]
        assert proc.returncode == 0, err
        assert "SIGTERM: stopping" in err and "Traceback" not in err and "robot=1" in err
        time.sleep(0.2)
        assert wire.startswith(P.start() + P.safe())
        assert wire.endswith(P.drive_direct(0, 0) + P.pause_resume_stream(False) + P.stop())
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)
        os.close(slave)
        shutil.rmtree(folder, ignore_errors=True)
        cleanup()


def _drain(fd: int, into: bytearray) -> None:
    while True:
        try:
            chunk = os.read(fd, 4096)
        except OSError:
            return
        if not chunk:
            return
        into.extend(chunk)
