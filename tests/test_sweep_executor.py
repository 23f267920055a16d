"""The sweep executor (sitl/experiments/executor.py): a Dask LocalCluster returns the rows the local run returns;
a sweep resumes after a stop; a run reads nothing from the submitting machine's working tree (its model travels
with it; a sweep runs from another directory); bad --cluster / --jobs are one line, exit 2; Ray where installed."""
from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import tempfile
from dataclasses import replace

import pytest

from runtime import cli
from sitl.experiments import dr_common as C
from sitl.experiments import executor
from sitl.experiments.executor import Carried
from sitl.ports import free_port

GREEDY = C.Cell("Greedy", "greedy", "NM_NI", "soft")
SETUP = replace(C.QUICK, max_objects=1)            # one object done ends a run: ~1.5 CPU s
JOBS = [(GREEDY, SETUP, 1), (GREEDY, SETUP, 2)]


def _rows(results):
    """The results without the wall times (the only column that depends on what ran them)."""
    return [{"run": {k: v for k, v in r["run"].items() if k != "wall_s"}, "objects": r["objects"]} for r in results]


def _same(a, b):
    """Rows equal, NaN equal to NaN (as JSON shows them)."""
    return json.dumps(_rows(a), sort_keys=True) == json.dumps(_rows(b), sort_keys=True)


@pytest.fixture(scope="module")
def local_rows(tmp_path_factory):
    """The two runs in this process (--jobs 1), from a directory that is not the repository's."""
    cwd = os.getcwd()
    os.chdir(tmp_path_factory.mktemp("elsewhere"))
    try:
        return C.run_all(JOBS, C.shipped_model(), 1)
    finally:
        os.chdir(cwd)


@pytest.mark.slow
def test_cluster_local_returns_the_rows_of_jobs_1(local_rows, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    checkpoint = tmp_path / "done.jsonl"
    on_cluster = C.run_all(JOBS, C.shipped_model(), 2, "local", checkpoint)
    assert [r["run"]["objects_done"] for r in local_rows] == [1, 1]          # each run did something to compare
    assert _same(on_cluster, local_rows)
    assert len(C.load_checkpoint(checkpoint)) == 2                           # each run written as it finished


def test_a_resumed_report_says_which_runs_its_wall_time_covers(local_rows):
    resumed = C.Execution(local_rows, "shipped", "mrta experiment dr-table3", 12.0, [], kept=1).describe(2)
    assert "wall time 12 s for the 1 of 2 runs this invocation ran; 1 came from an earlier one's checkpoint" in resumed
    assert "checkpoint" not in C.Execution(local_rows, "shipped", "mrta experiment dr-table3", 12.0, []).describe(2)


def test_resume_runs_only_what_a_stop_left(local_rows, tmp_path, monkeypatch):
    model = C.shipped_model()
    checkpoint = tmp_path / "done.jsonl"
    key = C.run_key(*JOBS[0], model)
    checkpoint.write_text(json.dumps({"key": key, "result": local_rows[0]}) + "\n" + '{"key": "cut sh')
    ran = []
    real = C.run_one
    monkeypatch.setattr(C, "run_one", lambda *a: ran.append(a[2]) or real(*a))
    done = C.load_checkpoint(checkpoint)                                     # the line a stop cut short: dropped
    assert list(done) == [key]
    resumed = C.run_all(JOBS, model, 1, None, checkpoint, done)
    assert ran == [2]                                                        # seed 1 kept, seed 2 run
    assert _same(resumed, local_rows)
    assert len(C.load_checkpoint(checkpoint)) == 2
    other = replace(SETUP, deadline=61.0)                                    # another setup: nothing kept
    assert C.run_key(GREEDY, other, 1, model) not in done


def test_a_carried_model_reads_nothing_of_the_submitter(local_rows, tmp_path, monkeypatch):
    src = tmp_path / "submit" / "model.json"
    src.parent.mkdir()
    shutil.copy(C.shipped_model(), src)
    carried = Carried.read(src)
    shutil.rmtree(src.parent)                                                # gone from the submitting side
    monkeypatch.chdir(tmp_path)
    path = carried.path()
    assert path.name == "model.json" and path.read_bytes() == C.shipped_model().read_bytes()
    assert not str(path).startswith(str(tmp_path))
    assert _same([C.run_one(*JOBS[0], carried)], local_rows[:1])


def test_a_sweep_runs_from_another_working_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)                    # no configs/, results/ or runtime/ here: all from the package
    assert cli.main(["experiment", "dr-table5", "--quick", "--seeds", "1", "--jobs", "1", "--time-limit", "5",
                     "--no-png", "--out", "t5"]) == 0
    runs = (tmp_path / "t5" / "dr_table5_runs.csv").read_text().splitlines()
    assert len(runs) == 1 + 4
    assert "shipped: runtime/allocation/dr/" in (tmp_path / "t5" / "dr_table5.md").read_text()


@pytest.mark.parametrize("given, expected", [
    (["--cluster", "here"], "mrta: --cluster 'here': expected local, tcp://HOST:PORT or ray://HOST:PORT"),
    (["--cluster", "http://127.0.0.1:1"], "expected local, tcp://HOST:PORT or ray://HOST:PORT"),
    (["--jobs", "0", "--cluster", "local"], "mrta: --jobs 0: expected at least 1"),
])
def test_bad_cluster_or_jobs_is_one_line(given, expected, tmp_path, capsys):
    assert cli.main(["experiment", "dr-table3", "--quick", *given, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert expected in err and "\n" not in err


def test_no_scheduler_at_the_address_is_one_line(tmp_path, monkeypatch, capsys):
    pytest.importorskip("distributed", reason="the [cluster] extra (dask, distributed) is not installed")
    port = free_port()                              # a free loopback port nobody listens on
    monkeypatch.setattr(executor, "CONNECT_TIMEOUT", 2.0)
    assert cli.main(["experiment", "dr-table3", "--quick", "--cluster", f"tcp://127.0.0.1:{port}",
                     "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"mrta: --cluster tcp://127.0.0.1:{port}: no Dask scheduler answered") and "\n" not in err


def test_without_dask_cluster_says_which_extra(monkeypatch, tmp_path, capsys):
    import builtins
    real = builtins.__import__

    def no_dask(name, *a, **k):
        if name == "distributed" or name.startswith("distributed."):
            raise ImportError(name)
        return real(name, *a, **k)
    monkeypatch.setattr(builtins, "__import__", no_dask)
    assert cli.main(["experiment", "dr-table3", "--quick", "--cluster", "local", "--out", str(tmp_path)]) == 2
    assert "pip install 'mrta-runtime[cluster]'" in capsys.readouterr().err


@pytest.mark.ray
@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("ray") is None,
                    reason="Ray is not installed (the [ray] extra, ~358 MB: not in the test extra)")
def test_ray_returns_the_rows_of_jobs_1(local_rows, tmp_path):
    gcs, client = free_port(), free_port()
    env = {**os.environ, "RAY_ADDRESS": ""}
    temp = tempfile.mkdtemp(prefix="ray-")          # short: Ray's socket paths must fit 107 characters
    subprocess.run(["ray", "start", "--head", "--node-ip-address", "127.0.0.1", "--port", str(gcs),
                    "--ray-client-server-port", str(client), "--num-cpus", "2", "--include-dashboard", "false",
                    "--temp-dir", temp], check=True, env=env, timeout=120, capture_output=True)
    try:
        on_ray = C.run_all(JOBS, C.shipped_model(), 2, f"ray://127.0.0.1:{client}")
    finally:
        subprocess.run(["ray", "stop", "--force"], env=env, timeout=60, capture_output=True)
        shutil.rmtree(temp, ignore_errors=True)
    assert _same(on_ray, local_rows)


def test_run_length_leaves_the_start_out():
    rate, until = C.run_length([250.0, 400.0, 550.0], 600.0, 400)     # one object per 150 s after the first
    assert rate == pytest.approx(1 / 150) and until == pytest.approx(250 + 399 * 150)
    assert C.run_length([300.0], 600.0, 10) == (1 / 600, 6000.0)      # one: the whole run's rate
    assert C.run_length([250.0, 400.0, 550.0], 600.0, 400, steady=False) == (3 / 600, 80000.0)   # start included
    assert C.run_length([], 600.0, 10) == (0.0, float("inf"))
    assert C.run_length([100.0, 200.0], 600.0, None) == (0.01, 600.0)  # no --objects: the time limit decides


def test_estimate_runs_one_calibration_run_per_kind_and_writes_nothing(tmp_path, capsys):
    assert cli.main(["experiment", "dr-table5", "--quick", "--seeds", "3", "--estimate", "--estimate-time", "3",
                     "--jobs", "2", "--out", str(tmp_path / "t5")]) == 0
    out = capsys.readouterr().out
    assert out.count("calibration: ") == 2                  # off-line and on-line cells cost apart
    assert "dr: 6 runs x" in out and "dr on-line: 6 runs x" in out and "CPU h" in out and "steady" in out
    assert not (tmp_path / "t5" / "dr_table5_runs.csv").exists()


def test_a_table_without_an_object_count_is_estimated_to_its_time_limit_not_the_calibrations(tmp_path, capsys):
    """Table 3 ends at its time limit (60 s quick): a 3 s calibration run is scaled to 60 s runs."""
    assert cli.main(["experiment", "dr-table3", "--quick", "--seeds", "1", "--estimate", "--estimate-time", "3",
                     "--out", str(tmp_path / "t3")]) == 0
    out = capsys.readouterr().out
    lines = [line for line in out.splitlines() if " runs x " in line]
    assert lines and all("(60-60 simulated s each" in line for line in lines), out
