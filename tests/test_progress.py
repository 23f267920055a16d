"""The one progress line of the long commands (sitl/experiments/progress.py)."""
from __future__ import annotations

import logging

from sitl.experiments.progress import Progress, bar


def test_bar_fills_by_share_done():
    assert bar(0, 5, 10) == "[----------] 0/5"
    assert bar(2, 5, 10) == "[####------] 2/5"
    assert bar(5, 5, 10) == "[##########] 5/5"
    assert bar(7, 5, 10) == "[##########] 7/5"          # more than planned: full, never longer
    assert bar(0, 0, 4) == "[####] 0/0"


def _progress(total, caplog, **kw):
    now = [100.0]
    p = Progress(total, logging.getLogger("mrta.test.progress"), width=10, clock=lambda: now[0], **kw)
    caplog.set_level(logging.INFO, "mrta.test.progress")
    return p, now


def test_each_run_logs_one_line_with_its_wall_time_and_the_estimate(caplog):
    p, now = _progress(5, caplog)
    now[0] += 372.0
    line = p.step("cell A seed 3: 12 objects done", wall=186.0)
    assert line == "[##--------] 1/5 cell A seed 3: 12 objects done (186 s wall; 372 s in all; ~1488 s left)"
    now[0] += 28.0
    assert p.step() == "[####------] 2/5 (400 s in all; ~600 s left)"
    assert [r.getMessage() for r in caplog.records] == [line, "[####------] 2/5 (400 s in all; ~600 s left)"]


def test_lines_thins_a_long_sweep_and_keeps_the_last(caplog):
    p, now = _progress(95, caplog, lines=10)
    for _ in range(95):
        now[0] += 1.0
        p.step("run")
    done = [int(r.getMessage().split("] ")[1].split("/")[0]) for r in caplog.records]
    assert len(done) == 10 and done[-1] == 95 and done == sorted(done)


def test_resumed_runs_fill_the_bar_but_not_the_rate(caplog):
    p, now = _progress(10, caplog, done=6)
    now[0] += 50.0
    assert p.step("n=4") == "[#######---] 7/10 n=4 (50 s in all; ~150 s left)"
