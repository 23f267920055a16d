"""The fleet dialect's bindings ship in the package (runtime/comms/_dialect/), generated from the XML the registry
composes now; the daemon uses them and writes nothing, so it runs as a user without a home.  A dialect composed at
run time (a method a test registers) still goes to the cache."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from runtime.comms import dialect

ROOT = Path(__file__).resolve().parents[1]
REGENERATE = "python -m runtime.comms.dialect --ship"


def test_shipped_bindings_were_generated_from_the_current_xml(tmp_path):
    assert (dialect.SHIPPED / "KEY").read_text().split()[0] == dialect.fleet_key(), \
        f"a dialect XML changed since runtime/comms/_dialect/ was generated: run {REGENERATE}"
    fresh = dialect.ship(tmp_path)                  # what the build step writes now, with this pymavlink
    assert fresh.read_bytes() == (dialect.SHIPPED / "mrta.py").read_bytes(), \
        f"runtime/comms/_dialect/mrta.py differs from what mavgen generates now: run {REGENERATE}"


def test_the_key_changes_with_any_dialect_xml(monkeypatch, tmp_path):
    before = dialect.fleet_key()
    edited = tmp_path / "mrta.xml"
    edited.write_bytes(dialect.XML_PATH.read_bytes().replace(b"</messages>", b"<!-- x --></messages>", 1))
    monkeypatch.setattr(dialect, "XML_PATH", edited)
    assert dialect.fleet_key() != before
    assert dialect.shipped() is None                 # stale bindings are never used


def test_load_uses_the_shipped_bindings_and_writes_no_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("MRTA_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(dialect, "_loaded", {})
    mod = dialect.load()
    assert mod.__name__ == dialect.SHIPPED_MODULE and Path(mod.__file__).parent == dialect.SHIPPED
    assert not (tmp_path / "cache").exists()


def test_a_method_registered_at_run_time_is_generated_into_the_cache(monkeypatch, tmp_path):
    from runtime.allocation import registry

    monkeypatch.setitem(registry.METHODS, "toy", "tests.toy_method:TOY")
    monkeypatch.setenv("MRTA_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(dialect, "_loaded", {})
    monkeypatch.setattr(dialect, "_by_file", {})
    assert dialect.shipped() is None
    mod = dialect.load()
    assert Path(mod.__file__).is_relative_to(tmp_path / "cache") and hasattr(mod, "MAVLINK_MSG_ID_MRTA_TOY_CLAIM")


def test_cache_falls_back_to_the_services_cache_directory(monkeypatch, tmp_path):
    for name in ("MRTA_CACHE_DIR", "XDG_CACHE_HOME"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("CACHE_DIRECTORY", f"{tmp_path}/a:{tmp_path}/b")     # systemd's CacheDirectory=
    assert dialect.cache_root() == tmp_path / "a"


_LINK = textwrap.dedent("""
    import os, sys
    from pathlib import Path
    from runtime.comms import codec, dialect
    from runtime.comms.link import MavlinkLink
    from runtime.messages import TaskRecord
    rx = MavlinkLink(1, "127.0.0.1:0", [])
    mav = dialect.load().MAVLink(None, srcSystem=2, srcComponent=1)
    sent = TaskRecord(2, 0, (2 << 16) | 5, 16, 1, 0, 0.0, 0.0, 0.0, 0.0, 1.5, -2.0)
    got = rx.feed(codec.encode(sent, mav), 0.0)
    rx.close()
    assert got == [sent], got
    print("decoded", type(got[0]).__name__, "from", Path(dialect.load().__file__).parent.name)
""")


@pytest.mark.parametrize("home", ["unset", "unwritable"])
def test_daemon_check_and_link_without_a_home(tmp_path, home):
    key = tmp_path / "fleet.key"
    env = {k: v for k, v in os.environ.items()
           if k not in ("HOME", "XDG_CACHE_HOME", "MRTA_CACHE_DIR", "CACHE_DIRECTORY")}
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    if home == "unwritable":
        (tmp_path / "home").write_text("")          # a file: nothing can be made under it, not even by root
        env["HOME"] = str(tmp_path / "home")
    mrta = [sys.executable, "-m", "runtime.cli"]
    subprocess.run([*mrta, "key", str(key)], cwd=ROOT, env=env, check=True, capture_output=True)
    robot = tmp_path / "create2.yaml"
    robot.write_text((ROOT / "configs/robots/create2.yaml").read_text().replace("/etc/mrta/fleet.key", str(key)))
    r = subprocess.run([*mrta, "daemon", str(robot), "--check"], cwd=ROOT, env=env, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith(f"{robot}: ok (robot 1")
    r = subprocess.run([sys.executable, "-c", _LINK], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "decoded TaskRecord from _dialect"
