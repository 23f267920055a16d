"""`mrta wdp`: JSON in, JSON out; every kind of bad input is exit 2 with one line naming the bid."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from runtime import cli
from runtime.allocation.coalition import winner_determination as wd
from runtime.errors import InputError

TABLE2 = {"robots": [1, 2, 3], "tasks": ["t1", "t2", "t3"], "bids": [
    {"task": "t1", "robots": [1, 2], "value": 3}, {"task": "t1", "robots": [2, 3], "value": 4},
    {"task": "t1", "robots": [3], "value": 2}, {"task": "t2", "robots": [1, 2], "value": 4},
    {"task": "t2", "robots": [2], "value": 5}, {"task": "t2", "robots": [3], "value": 3},
    {"task": "t3", "robots": [1, 3], "value": 4}, {"task": "t3", "robots": [2, 3], "value": 4},
    {"task": "t3", "robots": [3], "value": 8}]}


def _write(tmp_path, doc, name="bids.json"):
    p = tmp_path / name
    p.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    return p


@pytest.mark.parametrize("method", wd.METHODS[:-2] + ("milp",))
def test_json_output(tmp_path, capsys, method):
    rc = cli.main(["wdp", str(_write(tmp_path, TABLE2)), "--method", method, "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0
    assert set(out) == {"value", "assignment", "method", "nodes", "seconds"}
    assert out["value"] == 13
    assert out["assignment"] == {"t2": [2], "t3": [3]}
    assert out["method"].startswith(method)
    assert isinstance(out["nodes"], int) and out["seconds"] >= 0


def test_text_output_lists_tasks_and_leftovers(tmp_path, capsys):
    assert cli.main(["wdp", str(_write(tmp_path, TABLE2))]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("value 13  method auto")
    assert out[1:] == ["task t2: robots 2", "task t3: robots 3", "unassigned tasks: t1"]


def test_capped_search_is_marked(tmp_path, capsys):
    assert cli.main(["wdp", str(_write(tmp_path, TABLE2)), "--method", "bfs", "--node-limit", "4", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["capped"] is True and out["nodes"] == 4


def test_console_script_reads_stdin():
    proc = subprocess.run([sys.executable, "-m", "runtime.cli", "wdp", "-", "--json"], input=json.dumps(TABLE2),
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["value"] == 13


def _bad(**change):
    doc = json.loads(json.dumps(TABLE2))
    doc["bids"][4].update(change)
    return doc


@pytest.mark.parametrize("doc, needle", [
    (_bad(robots=[9]), "bid 4: unknown robot 9"),
    (_bad(task="t9"), "bid 4: unknown task 't9'"),
    (_bad(robots=[]), "bid 4: empty coalition"),
    (_bad(robots=[2, 2]), "bid 4: robot 2 appears twice"),
    (_bad(value=-1), "bid 4: value must be a finite number >= 0"),
    (_bad(value="5"), "bid 4: value must be a finite number >= 0"),
    (_bad(value=True), "bid 4: value must be a finite number >= 0"),
    (_bad(robots="2"), 'bid 4: "robots" must be a list'),
    ('{"robots": [1], "tasks": [1], "bids": [{"task": 1, "robots": [1], "value": NaN}]}', "bid 0: value must be a finite"),
    ('{"robots": [1], "tasks": [1], "bids": [{"task": 1, "robots": [1], "value": Infinity}]}', "bid 0: value must be a finite"),
    ('{"robots": [1], "tasks": [1], "bids": [{"task": 1, "robots": [1]}]}', 'bid 0: missing "value"'),
    ('{"robots": [1], "tasks": [1], "bids": [7]}', "bid 0: expected an object"),
    ('{"robots": [1, 1], "tasks": [1], "bids": []}', '"robots"[1]: id 1 is listed twice'),
    ('{"robots": [1.5], "tasks": [1], "bids": []}', '"robots"[0]: expected an integer or string id'),
    ('{"tasks": [1], "bids": []}', '"robots": expected a list'),
    ('[1, 2]', "expected an object"),
    ('{"robots": [1], "tasks": [1], "bids": [', "expected JSON (Expecting value at line 1"),
])
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, doc, needle):
    path = _write(tmp_path, doc)
    assert cli.main(["wdp", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"mrta: {path}: ")
    assert needle in err


def test_missing_file_and_bad_node_limit(tmp_path, capsys):
    assert cli.main(["wdp", str(tmp_path / "none.json")]) == 2
    assert "expected a readable bids file" in capsys.readouterr().err
    assert cli.main(["wdp", str(_write(tmp_path, TABLE2)), "--node-limit", "0"]) == 2
    assert "--node-limit 0" in capsys.readouterr().err


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-5, 5) | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=3),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.sampled_from(["robots", "tasks", "bids", "task", "value", "x"]), inner, max_size=4),
    max_leaves=20)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(doc=json_values)
def test_random_documents_only_ever_raise_input_error(doc):
    try:
        p = wd.parse_problem(doc)
    except InputError as exc:
        assert "\n" not in str(exc)
    else:
        assert wd.solve(p).value >= 0


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.integers(0, len(json.dumps(TABLE2))), junk=st.binary(max_size=8))
def test_truncated_and_garbled_files_only_ever_raise_input_error(tmp_path, cut, junk):
    path = tmp_path / "cut.json"
    path.write_bytes(json.dumps(TABLE2).encode()[:cut] + junk)
    try:
        p = wd.load_problem(path)
    except InputError as exc:
        assert "\n" not in str(exc) and str(exc).startswith(str(path))
    else:                                   # the whole file, or a prefix that junk completed
        res = wd.solve(p)
        assert wd.check_feasible(p, res.winners) and res.value >= 0
