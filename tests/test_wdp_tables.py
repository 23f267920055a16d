"""`mrta experiment wdp-tables` on a reduced grid: files, paper numbers beside ours, caps, notes."""
from __future__ import annotations

import csv
import random
import re

import pytest

from runtime import cli
from sitl.experiments import wdp_tables


def test_reduced_reproduction_writes_csv_markdown_png(tmp_path):
    out = tmp_path / "wdp"
    rc = cli.main(["experiment", "wdp-tables", "--out", str(out), "--runs", "2", "--tasks", "10",
                   "--random-bids", "10,20", "--uniform-bids", "40", "--node-cap", "3000",
                   "--sensitivity-sizes", "1,3"])
    assert rc == 0
    rows = list(csv.DictReader((out / "wdp_tables.csv").open()))
    main = [r for r in rows if r["random_sizes"] in ("1-10", "3")]
    assert [(r["distribution"], r["bids"]) for r in main] == [("random", "10"), ("random", "20"), ("uniform", "40")]
    assert [r["paper_bfs_nodes"] for r in main] == ["106", "979", "2364"]
    assert [r["paper_idastar_nodes"] for r in main] == ["24", "75", "61"]
    assert len(rows) == 5                                    # + two sensitivity cells
    md = (out / "wdp_tables.md").read_text()
    for heading in ("Table 3", "Table 4", "Table 5", "Table 6", "Notes", "Sensitivity"):
        assert heading in md
    assert re.search(r"\| 10 \| BFS \| \d+ \(106\) \|", md)
    # every flagged cell names a note, and every named note is written out
    flagged = md.split("## Cells more than 2x")[1].split("## ")[0]
    for note in set(re.findall(r"note ([A-Z])", flagged)):
        assert f"**{note}.**" in md
    capped = [r for r in rows if int(r["idastar_capped_runs"]) or int(r["bfs_capped_runs"])]
    for r in capped:
        assert "capped at 3000" in md
    assert (out / "wdp_tables.png").stat().st_size > 10_000


def test_capped_cells_are_reported_as_capped_not_as_numbers(tmp_path):
    out = tmp_path / "cap"
    assert cli.main(["experiment", "wdp-tables", "--out", str(out), "--runs", "1", "--tasks", "20",
                     "--random-bids", "10", "--uniform-bids", "160", "--node-cap", "500",
                     "--sensitivity-sizes", "none", "--no-png"]) == 0
    md = (out / "wdp_tables.md").read_text()
    table5 = md.split("## Table 5")[1].split("## ")[0]
    assert "| 20 | BFS | capped at 500 (1/1 runs) |" in table5
    assert not (out / "wdp_tables.png").exists()


def test_generator_follows_the_paper_distributions():
    rng = random.Random(0)
    p = wdp_tables.make_problem(rng, 10, 15, 400, "uniform")
    assert len(p.bids) == 400 and all(len(b.robots) == 3 for b in p.bids)
    p = wdp_tables.make_problem(rng, 10, 15, 400, "random")
    sizes = {len(b.robots) for b in p.bids}
    assert sizes == set(range(1, 11))
    assert {b.task for b in p.bids} <= set(p.tasks) and all(1 <= b.value <= 100 for b in p.bids)


@pytest.mark.parametrize("argv, needle", [
    (["--runs", "0"], "--runs 0"),
    (["--tasks", "a,b"], "--tasks 'a,b'"),
    (["--values", "5"], "--values '5'"),
    (["--random-sizes", "0,3"], "at least 1 robot"),
])
def test_bad_arguments_exit_2(tmp_path, capsys, argv, needle):
    assert cli.main(["experiment", "wdp-tables", "--out", str(tmp_path)] + argv) == 2
    assert needle in capsys.readouterr().err
