"""What a robot installs (pip install mrta-runtime, no [sitl] extra): the robot side imports and runs without
pybullet and matplotlib, the simulator's commands say in one line what to install, and the package metadata
says what it is (docs/deploy.md)."""
from __future__ import annotations

import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import pytest

from runtime import cli

ROOT = Path(__file__).resolve().parents[1]

# A process without the [sitl] extra: importing pybullet or matplotlib fails as if they were not installed.
_NO_SIMULATOR = textwrap.dedent("""
    import importlib.abc, sys
    class NoSimulator(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in ("pybullet", "pybullet_data", "matplotlib"):
                raise ModuleNotFoundError(f"No module named {name!r}", name=name)
            return None
    sys.meta_path.insert(0, NoSimulator())
""")


def _run(code: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", _NO_SIMULATOR + textwrap.dedent(code), *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)


def test_the_poison_works():
    r = _run("import pybullet")
    assert r.returncode != 0 and "No module named 'pybullet'" in r.stderr


def test_every_runtime_module_imports_without_the_simulator():
    r = _run("""
        import importlib, pkgutil, runtime
        names = [m.name for m in pkgutil.walk_packages(runtime.__path__, "runtime.")]
        for name in names:
            importlib.import_module(name)
        loaded = sorted({m.split(".")[0] for m in sys.modules} & {"pybullet", "matplotlib", "sitl"})
        print(len(names), loaded)
    """)
    assert r.returncode == 0, r.stderr
    count, loaded = r.stdout.split(" ", 1)
    assert int(count) > 100 and loaded.strip() == "[]"


@pytest.mark.parametrize("command", ["daemon", "mission", "key"])
def test_robot_commands_print_their_help_without_the_simulator(command):
    r = _run("""
        from runtime import cli
        try:
            cli.main(sys.argv[1:])
        except SystemExit as e:
            loaded = sorted({m.split(".")[0] for m in sys.modules} & {"pybullet", "matplotlib", "sitl"})
            print("exit", e.code, loaded)
    """, command, "--help")
    assert r.returncode == 0, r.stderr
    assert f"usage: mrta {command}" in r.stdout
    assert r.stdout.rstrip().endswith("exit 0 []")      # and the simulator's modules were never imported


def test_mrta_help_lists_the_simulator_commands_without_the_simulator():
    r = _run("""
        from runtime import cli
        sys.exit(cli.main(sys.argv[1:]))
    """, "--help")
    assert r.returncode == 0, r.stderr          # the sitl modules import pybullet and matplotlib lazily
    assert "sitl " in r.stdout and "experiment " in r.stdout and "daemon " in r.stdout


@pytest.mark.parametrize("argv", [["sitl", "run", "create2_4"], ["experiment", "formation-world"]])
def test_simulator_commands_say_what_to_install(argv):
    r = _run("""
        from runtime import cli
        sys.exit(cli.main(sys.argv[1:]))
    """, *argv)
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and "pip install 'mrta-runtime[sitl]'" in r.stderr, r.stderr
    assert r.stderr.startswith(f"mrta: {argv[0]}: ")


def test_version_comes_from_the_package_metadata(capsys):
    from importlib.metadata import version

    with pytest.raises(SystemExit) as exit_:
        cli.main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip() == f"mrta {version('mrta-runtime')}"


def test_version_without_metadata_says_unknown(monkeypatch):
    import importlib.metadata as md

    def missing(name):
        raise md.PackageNotFoundError(name)
    monkeypatch.setattr(md, "version", missing)
    assert cli.version() == "unknown"


def _project() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def test_base_dependencies_leave_the_simulator_to_the_sitl_extra():
    project = _project()
    names = {d.split(">")[0].split("=")[0].split("[")[0].strip().lower() for d in project["dependencies"]}
    assert not names & {"pybullet", "matplotlib", "filterpy"}     # filterpy requires matplotlib
    sitl = {d.split(">")[0].lower() for d in project["optional-dependencies"]["sitl"]}
    assert {"pybullet", "matplotlib"} <= sitl
    assert "mrta-runtime[sitl]" in project["optional-dependencies"]["test"]   # make run / make test get pybullet
    assert not any("pytest-benchmark" in d for d in project["optional-dependencies"]["test"])


def test_metadata_a_user_reads_with_pip_show():
    project = _project()
    assert project["description"] and project["requires-python"] == ">=3.11"
    assert "Programming Language :: Python :: 3.11" in project["classifiers"]
    # no LICENSE file in the repository: no licence is claimed
    assert not list(ROOT.glob("LICEN[CS]E*")) and "license" not in project
