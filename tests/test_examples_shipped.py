"""The example configs ship in the package (runtime/examples is the repository's configs/), `mrta sitl run` takes a
shipped fleet by name as well as by path, and the wheel holds runtime and sitl only (benchmarks/wheel_contents.py)."""
from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

from runtime import cli
from sitl import fleet_config as FC

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("wheel_contents", ROOT / "benchmarks" / "wheel_contents.py")
wheel_contents = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(wheel_contents)


def test_the_examples_are_the_repositorys_configs():
    assert FC.EXAMPLES.resolve() == (ROOT / "configs").resolve()
    assert "create2_4" in FC.shipped_fleets() and len(FC.shipped_fleets()) == len(list((ROOT / "configs/fleets").glob("*.yaml")))


@pytest.mark.parametrize("name", ["create2_4", "create2_4.yaml"])
def test_a_shipped_fleet_is_found_by_name(name):
    assert FC.find_fleet(name) == FC.EXAMPLES / "fleets" / "create2_4.yaml"


def test_a_path_wins_over_a_name(tmp_path, monkeypatch):
    mine = tmp_path / "create2_4"
    mine.write_text((ROOT / "configs/fleets/create2_4.yaml").read_text())
    monkeypatch.chdir(tmp_path)
    assert FC.find_fleet("create2_4") == Path("create2_4")
    assert FC.find_fleet(str(ROOT / "configs/fleets/can_2.yaml")) == ROOT / "configs/fleets/can_2.yaml"


@pytest.mark.parametrize("name", sorted(FC.shipped_fleets()))
def test_every_shipped_fleet_loads_by_name(name):
    fleet = FC.load_fleet(FC.find_fleet(name))          # its robots and world resolve inside the examples
    assert fleet.robots


@pytest.mark.parametrize("arg", ["create2_5", "fleets/create2_4", "create2_4.yml"])
def test_neither_a_file_nor_a_shipped_name_is_one_line_listing_the_names(arg, capsys):
    assert cli.main(["sitl", "run", arg]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"mrta: fleet: {arg!r} is neither a fleet file nor a shipped fleet")
    assert "create2_4, create2_4_boxes" in err


def test_wheel_problems_are_found():
    good = [f"{m}" for m in wheel_contents.MUST] + [f"runtime/examples/{p.relative_to(ROOT / 'configs')}"
                                                     for p in (ROOT / "configs").glob("*/*")]
    good += ["sitl/__init__.py", "mrta_runtime-0.1.0.dist-info/METADATA"]
    assert wheel_contents.problems(good) == []
    bad = [n for n in good if n != "runtime/comms/_dialect/KEY"] + ["tests/__init__.py"]
    assert wheel_contents.problems(bad) == ["top-level 'tests': expected only ['runtime', 'sitl'] and the dist-info",
                                            "missing runtime/comms/_dialect/KEY"]


def test_the_built_wheel_holds_runtime_and_sitl_with_the_dialect_and_examples(tmp_path):
    try:
        wheel = wheel_contents.build(tmp_path)
    except subprocess.CalledProcessError as e:
        if "Could not find a version" in e.stderr or "connection" in e.stderr.lower():
            pytest.skip(f"pip cannot fetch the build backend: {e.stderr.strip().splitlines()[-1]}")
        raise
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "wheel_contents.py"), str(wheel)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout
    assert [ln.split()[0] for ln in r.stdout.splitlines()[1:]] == ["*.dist-info", "runtime", "sitl"]
    assert wheel_contents.stale(wheel) == []           # every module is this checkout's, none left from a build/
