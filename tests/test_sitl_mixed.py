"""A mixed fleet, nothing but configs changed: a Create 2 (OI on a pty), a Pioneer 3-DX on serial and one over TCP
(ARCOS), and a CAN base of two CiA 402 drives (socketcand hub), as `mrta sitl run` runs them."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from tests.sitl_util import ROOT, shipped_fleet


@pytest.mark.slow
def test_mixed_4_reaches_its_formation_with_one_daemon_process_per_robot(tmp_path):
    fleet = shipped_fleet(tmp_path, "mixed_4.yaml")
    run_dir = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "runtime.cli", "sitl", "run", str(fleet), "--run-dir", str(run_dir),
                           "--json", str(tmp_path / "res.json")], cwd=ROOT, capture_output=True, text=True, timeout=300)
    print(proc.stdout[-1500:])
    assert proc.returncode == 0, proc.stderr[-2000:]
    res = json.loads((tmp_path / "res.json").read_text())
    assert res["goal_met"] and res["valid"] and not res["lost"]
    assert all(err < 0.2 for err in res["final_error"].values()), res["final_error"]
    manifest = json.loads((run_dir / "manifest.json").read_text())
    bases = {r["id"]: r["base"] for r in manifest["robots"]}
    assert [bases[i]["type"] for i in (1, 2, 3, 4)] == ["create_oi", "arcos", "arcos", "cia402"]
    assert bases[2]["port"].startswith("/dev/pts/") and bases[3]["port"].startswith("socket://127.0.0.1:")
    assert bases[4]["interface"] == "socketcand" and bases[4]["channel"]
