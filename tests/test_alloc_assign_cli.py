"""`mrta assign`: JSON output schema, plain table, exit 2 with one line on every kind of bad input."""
from __future__ import annotations

import json

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from runtime import cli
from runtime.allocation.formation.assign_cli import load_problem
from runtime.allocation.formation.assignment import global_cost, hungarian, is_permutation
from runtime.errors import InputError

COSTS = [[4, 1, 3], [2, 0, 5], [3, 2, 2]]


def write(tmp_path, data, name="problem.json"):
    p = tmp_path / name
    p.write_text(data if isinstance(data, str) else json.dumps(data))
    return p


@pytest.mark.parametrize("method", ["auction", "bs", "rtma", "hungarian"])
def test_json_output_schema(tmp_path, capsys, method):
    p = write(tmp_path, {"costs": COSTS})
    assert cli.main(["assign", str(p), "--method", method, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"assignment", "cost", "messages"}
    assert is_permutation(out["assignment"], 3)
    assert out["cost"] == pytest.approx(global_cost(COSTS, out["assignment"]))
    assert isinstance(out["messages"], int) and out["messages"] >= 0
    assert (out["messages"] == 0) == (method == "hungarian")
    if method in ("auction", "hungarian"):
        assert out["cost"] == hungarian(COSTS)[1]


def test_positions_give_straight_line_costs(tmp_path, capsys):
    p = write(tmp_path, {"robots": [[0, 0], [2.5, 0]], "tasks": [[1, 0], [-1.5, 0]]})
    assert cli.main(["assign", str(p), "--method", "bs", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["assignment"] == [0, 1] and out["cost"] == pytest.approx(5.0)


def test_plain_output_is_a_table(tmp_path, capsys):
    p = write(tmp_path, {"costs": COSTS})
    assert cli.main(["assign", str(p)]) == 0
    text = capsys.readouterr().out
    lines = text.splitlines()
    assert lines[0].startswith("method auction: 3 robots")
    assert lines[1].split() == ["robot", "task", "cost"]
    assert len(lines) == 6 and lines[-1].startswith("total 5.000   optimum 5.000   error 0.00 %")


def test_world_costs_come_from_the_planner(tmp_path, capsys):
    root = __import__("pathlib").Path(__file__).resolve().parents[1]
    world = root / "configs" / "worlds" / "boxes_10m.yaml"
    # the box at the origin blocks the straight line between (-2, 0) and (2, 0)
    p = write(tmp_path, {"robots": [[-2, 0], [4, 4]], "tasks": [[2, 0], [4, 3]], "world": str(world)})
    costs, _, _ = load_problem(p)
    assert costs[0, 0] > 4.0 and costs[1, 1] == pytest.approx(1.0)
    assert cli.main(["assign", str(p), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["assignment"] == [0, 1]


BAD = [
    ("{not json", "expected JSON"),
    ("[1, 2]", "expected a JSON object"),
    ({"cost": [[1]]}, 'missing key "robots"'),
    ({"robots": [[0, 0]]}, 'missing key "tasks"'),
    ({"costs": [[1, 2], [3]]}, "costs row 1: has 1 entries, expected 2"),
    ({"costs": [[1, 2, 3], [4, 5, 6]]}, "costs row 0: has 3 entries, expected 2"),
    ({"costs": [[1, -2], [3, 4]]}, "expected a non-negative number"),
    ('{"costs": [[1, NaN], [3, 4]]}', "expected a finite number"),
    ('{"costs": [[1, Infinity], [3, 4]]}', "expected a finite number"),
    ({"costs": [[1, 1e999], [3, 4]]}, "expected a finite number"),
    ({"costs": [[1, "2"], [3, 4]]}, "expected a number"),
    ('{"costs": [[1, 1%s], [3, 4]]}' % ("0" * 400), "expected a finite number"),
    ({"costs": []}, "expected a non-empty list"),
    ({"costs": 5}, "expected a non-empty list"),
    ({"robots": [[0, 0], [1]], "tasks": [[0, 0], [1, 1]]}, "robots[1]: expected [x, y]"),
    ({"robots": [[0, 0]], "tasks": [[0, 0, 0]]}, "tasks[0]: expected [x, y]"),
    ({"robots": [[0, 0]], "tasks": "here"}, "tasks: expected a non-empty list"),
    ({"robots": [[0, 0], [1, 1]], "tasks": [[0, 0]]}, "2 robots and 1 tasks"),
    ('{"robots": [[0, NaN]], "tasks": [[0, 0]]}', "robots[0]: expected finite"),
    ({"robots": [[0, 0]], "tasks": [[1, 1]], "world": 3}, "world: expected a path"),
]


@pytest.mark.parametrize("data, words", BAD, ids=[w for _, w in BAD])
def test_bad_input_exits_2_with_one_line_naming_file_and_problem(tmp_path, capsys, data, words):
    p = write(tmp_path, data)
    assert cli.main(["assign", str(p), "--json"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith(f"mrta: {p}: ") and words in lines[0]


def test_missing_file_and_missing_world(tmp_path, capsys):
    assert cli.main(["assign", str(tmp_path / "nope.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "nope.json" in err and "readable" in err
    p = write(tmp_path, {"robots": [[0, 0]], "tasks": [[1, 1]], "world": "no/such/world.yaml"})
    assert cli.main(["assign", str(p)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "world.yaml" in err


@pytest.mark.parametrize("value", ["0", "-1", "3601", "1e308", "inf", "nan"])
def test_bad_bid_timeout(tmp_path, capsys, value):
    p = write(tmp_path, {"costs": COSTS})
    assert cli.main(["assign", str(p), "--bid-timeout", value]) == 2
    assert capsys.readouterr().err == f"mrta: --bid-timeout: expected a number in (0, 3600], got {float(value)!r}\n"


GOOD = json.dumps({"costs": COSTS, "robots": [[0, 0]], "tasks": [[1, 2]]})


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.one_of(st.binary(max_size=60), st.integers(0, len(GOOD)).map(lambda k: GOOD[:k].encode()),
                 st.recursive(st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=4),
                              lambda kids: st.lists(kids, max_size=4)
                              | st.dictionaries(st.sampled_from(["costs", "robots", "tasks", "x"]), kids,
                                                max_size=3), max_leaves=12).map(lambda v: json.dumps(v).encode())))
def test_random_and_truncated_files_load_or_raise_input_error(tmp_path, data):
    p = tmp_path / "fuzz.json"
    p.write_bytes(data)
    try:
        costs, robots, tasks = load_problem(p)
    except InputError as exc:
        assert "\n" not in str(exc) and str(exc).startswith(str(p))
    else:
        assert costs.shape[0] == costs.shape[1] >= 1


# --------------------------------------------------------------------------- hostile input (issue 14)

@pytest.mark.parametrize("data, words", [
    ({"robots": [[i, 0] for i in range(251)], "tasks": [[i, 1] for i in range(251)]},
     "expected at most 250 robots for --method auction"),
    ({"robots": [[1e308, 0], [0, 0]], "tasks": [[-1e308, 0], [1, 1]]}, "robots[0]: expected finite coordinates"),
    ({"robots": [[10 ** 400, 0]], "tasks": [[0, 0]]}, "robots[0]: expected finite coordinates"),
    ({"costs": [[1e308, 1e308], [1e308, 1e308]]}, "costs[0][0]: expected at most 1e+30"),
    ('{"costs": [[1' + "0" * 5000 + "]]}", "expected JSON numbers Python can read"),
    ({"robots": [[i, 0] for i in range(4001)], "tasks": [[i, 1] for i in range(4001)]},
     "expected at most 4000 robots and tasks"),
])
def test_huge_problems_and_values_exit_2_with_one_line(tmp_path, capsys, data, words):
    p = write(tmp_path, data)
    assert cli.main(["assign", str(p)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"mrta: {p}: ") and words in err, err


def test_hungarian_takes_more_than_250_robots(tmp_path, capsys):
    p = write(tmp_path, {"robots": [[i, 0] for i in range(251)], "tasks": [[i, 1] for i in range(251)]})
    assert cli.main(["assign", str(p), "--method", "hungarian", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["cost"] == pytest.approx(251)
