"""`mrta experiment dr-calibration`: the interference samples (n, d_m, I) of paper 000 section 4.2.1."""
from __future__ import annotations

import csv
import math

import pytest

from runtime.errors import InputError
from sitl.experiments import dr_calibration as cal
from sitl.foraging import scenario


def test_one_case_row_is_consistent():
    row = cal.run_case(1, 140, 120.0, seed=1, dt=0.05)
    assert row["n"] == 1 and row["d_m"] == pytest.approx(1.40) and row["duration_s"] == pytest.approx(120.0)
    ideal = scenario.work_capacity(1.40, 2.0, 0.25, 0.12)
    assert row["ideal_wu_per_s"] == pytest.approx(ideal)
    assert row["I_wu_per_s"] == pytest.approx(ideal - row["moved_wu"] / 120.0)
    assert row["I_wu_per_tu"] == pytest.approx(row["I_wu_per_s"] * 0.12)
    assert row["moved_wu"] == 2.0 * row["trips"] > 0
    assert 0.5 < row["fraction_of_ideal"] < 1.1                 # one robot alone: near eq. 5 (turns cost time)


def test_interference_grows_with_the_group_at_a_short_distance():
    one = cal.run_case(1, 140, 120.0, seed=1, dt=0.05)
    three = cal.run_case(3, 140, 120.0, seed=1, dt=0.05)
    assert three["I_wu_per_s"] > one["I_wu_per_s"]
    assert three["fraction_of_ideal"] < one["fraction_of_ideal"]


def test_background_groups_work_their_own_objects_and_only_the_fixed_one_counts():
    from sitl.foraging import harness
    cfg = cal.config(2, 140, 120.0, seed=1, dt=0.05, extra=1)
    assert cfg.ids == (1, 2, 3, 4) and len(cfg.background) == 2
    for x, y, n in cfg.background:            # BACKGROUND_AT from D, +-BACKGROUND_TURN from the diagonal, one robot
        assert math.hypot(x, y) == pytest.approx(cal.BACKGROUND_AT) and n == 1
    fr = harness.ForagingRun(cfg)
    try:
        res = fr.run()
        commits = {r: fr.robots[r].commitments[0] for r in cfg.ids}
    finally:
        fr.close()
    assert commits[1].task_id == commits[2].task_id != commits[3].task_id != commits[4].task_id
    assert commits[1].partners == (2,) and commits[2].partners == (1,) and commits[3].partners == ()
    fixed, *others = res.objects
    assert (fixed.x, fixed.y) == pytest.approx(cfg.fixed_object) and all(o.delivered > 0 for o in others)
    row = cal.run_case(2, 140, 120.0, seed=1, dt=0.05, extra=1)
    assert row["background"] == 1 and row["moved_wu"] == pytest.approx(fixed.delivered)
    assert row["moved_wu"] == 2.0 * row["trips"] > 0             # the fixed group's trips only
    with pytest.raises(InputError, match="foraging background"):
        harness.ForagingRun(harness.ForagingConfig(robots=2, method=None, background=((0.0, 3.0, 2),)))


@pytest.mark.slow
def test_quick_run_writes_the_samples_and_the_report(tmp_path):
    import argparse
    parser = argparse.ArgumentParser()
    parser.add_argument("--out")
    cal.add_arguments(parser)
    samples = tmp_path / "samples.csv"
    args = parser.parse_args(["--out", str(tmp_path / "out"), "--quick", "--jobs", "2", "--samples", str(samples)])
    assert cal.run(args) == 0
    with samples.open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 3 * 2                                    # robots 1, 2, 4 x 140 and 400 du
    assert {"n", "d_m", "I_wu_per_s"} <= set(rows[0])
    assert all(math.isfinite(float(r["I_wu_per_s"])) for r in rows)
    get = {(int(r["n"]), int(r["d_du"])): float(r["I_wu_per_s"]) for r in rows}
    assert get[(4, 140)] > get[(1, 140)]
    for name in ("dr_calibration.csv", "dr_calibration.md", "dr_calibration.png"):
        assert (tmp_path / "out" / name).stat().st_size > 0
    md = (tmp_path / "out" / "dr_calibration.md").read_text()
    assert "Fraction of the ideal capacity" in md and "interference grows with the number of robots" in md
    from runtime.allocation.dr.interference import InterferenceModel
    model = InterferenceModel.load(tmp_path / "out" / "model.json")          # fitted on these samples, not shipped
    assert len(model.samples) == 6 and "The interference model fitted" in md
    assert model.predict(4, 1.4) > model.predict(1, 1.4)
    # resuming from the CSV runs nothing again and gives the same samples
    args = parser.parse_args(["--out", str(tmp_path / "out"), "--quick", "--jobs", "1", "--samples", str(samples),
                              "--resume", str(tmp_path / "out" / "dr_calibration.csv")])
    before = samples.read_text()
    assert cal.run(args) == 0 and samples.read_text() == before


@pytest.mark.parametrize("argv, why", [(["--robots", "0-3"], "--robots '0-3': expected group sizes"),
                                       (["--robots", "a"], "--robots 'a': expected a range"),
                                       (["--distances", "140,900"], "--distances '140,900': expected du between"),
                                       (["--jobs", "0"], "--jobs 0: expected at least 1"),
                                       (["--background", "7"], "--background 7: expected 0 to 6")])
def test_bad_arguments_are_one_line_errors(argv, why, tmp_path):
    import argparse
    parser = argparse.ArgumentParser()
    parser.add_argument("--out", default=str(tmp_path))
    cal.add_arguments(parser)
    with pytest.raises(InputError, match=why.replace("(", r"\(").replace(")", r"\)")):
        cal.run(parser.parse_args(argv))
