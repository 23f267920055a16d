"""`mrta experiment dr-table3|dr-table4|dr-table5` (paper 000 sections 6.2-6.3) and the dr agent in the foraging
harness: objects get leaders and groups, are delivered and replaced, the harness's weight agrees with the
agents' books; each command writes its CSV, PNG and markdown with the paper's numbers; a strategy difference
the paper claims that holds in a small case; bad options and a missing model are one line and exit 2."""
from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from runtime import cli
from runtime.allocation.dr import model as M
from runtime.allocation.dr.interference import InterferenceModel
from runtime.allocation.dr.options import DrOptions
from sitl.experiments import dr_common as C
from sitl.experiments import dr_table3, dr_table4, dr_table5
from sitl.foraging.harness import ForagingConfig, ForagingRun
from sitl.foraging.scenario import Dist

# Bumpers only and a deadline one robot meets: with the sonar, or two robots on one object, the executive cannot
# settle robots meeting head-on today (tests/test_foraging_deadlock.py), and what is tested here is the glue.
SMALL = ForagingConfig(robots=3, method="dr", options=DrOptions(strategy="NM_NI", utility="soft"), seed=1,
                       time_limit=200.0, max_objects=4, objects=3, weight=Dist.const(4.0), deadline=Dist.const(200.0),
                       size=6.0, sonar=False)


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    """A small interference model: I grows with the group and shrinks with the distance."""
    samples = [(n, d, 0.02 * (n - 1) ** 1.5 / (1 + d)) for n in range(1, 9) for d in (1.0, 2.5, 4.0, 6.0)]
    path = tmp_path_factory.mktemp("model") / "model.json"
    InterferenceModel.from_samples(samples, search=False, source="test").save(path)
    return path


def _rows(path):
    return list(csv.DictReader(path.open()))


def test_dr_runs_in_the_harness_and_its_books_agree_with_the_world():
    fr = ForagingRun(SMALL)
    try:
        leaders = {}

        def observe(run):
            for r, rb in run.robots.items():
                agent = rb.node.agent
                for t in agent.coalitions():
                    if agent.role(t) == "leader":
                        leaders.setdefault(t, set()).add(r)
        res = fr.run(observe)
        finished = {t: f for rb in fr.robots.values() for t, f in rb.node.agent.finished.items()}
    finally:
        fr.close()
    done = res.finished
    assert len(done) == SMALL.max_objects                         # delivered ...
    assert len(res.objects) > SMALL.objects                       # ... and replaced as they were done
    for o in done:
        assert o.delivered == o.weight == 4.0 and o.pile == 0.0
        assert len(leaders[o.task]) == 1                          # one leader each, never two
        f = finished[o.task]                                      # the leader's books: the world's weight
        assert f.delivered == pytest.approx(o.delivered) and f.weight == o.weight
        assert abs(f.finished - f.appeared - o.elapsed) <= 0.2    # fT as the agents saw it, within a tick or two
        assert max(n for _, n in o.coalition) >= 1
    assert res.moved == pytest.approx(sum(f.delivered for f in finished.values()) +
                                      sum(o.delivered for o in res.objects if o.finished is None))


def test_a_tight_deadline_makes_the_leader_recruit_a_group():
    """40 wu, 108 s, 4 robots: one robot needs ~200 s (eq. 5), so the leader awards the others (NM_NI, I = 0)."""
    cfg = ForagingConfig(robots=4, method="dr", options=DrOptions(strategy="NM_NI"), seed=2, time_limit=15.0,
                         objects=1, weight=Dist.const(40.0), deadline=Dist.const(108.0), size=6.0, sonar=False)
    fr = ForagingRun(cfg)
    try:
        res = fr.run()
        (obj,) = res.objects
        leader = next(rb.node.agent for rb in fr.robots.values() if rb.node.agent.role(obj.task) == "leader")
        view = leader.leader_view(obj.task)
    finally:
        fr.close()
    d = math.hypot(obj.x, obj.y)
    one = M.work_capacity(2.0, 0.25, d, 0.12)
    need = math.ceil(40.0 / (108.0 * one))
    assert need >= 2
    assert len(view.members) >= min(need, 4)
    assert max(n for _, n in obj.coalition) >= min(need, 4)


def test_greedy_puts_more_robots_on_an_object_than_nm_i(model_file):
    setup = C.Setup(robots=5, objects=1, weight=4.0, deadline=200.0, time_limit=12.0, size=6.0, sonar=False)
    greedy = C.run_one(C.Cell("Greedy", "greedy", "NM_NI"), setup, 3, model_file)["run"]
    nm_i = C.run_one(C.Cell("NM_I", "sr", "NM_I"), setup, 3, model_file)["run"]
    assert nm_i["max_group"] == 1               # the leader alone meets the deadline: it recruits nobody
    assert greedy["max_group"] >= 4             # Greedy awards every bidder


def _args(**given):
    import argparse
    base = dict(time_limit=None, no_sonar=False, deadline=None)
    return argparse.Namespace(**{**base, **given})


def test_dr_table3_quick_writes_its_files(tmp_path, model_file, capsys):
    out = tmp_path / "t3"
    assert cli.main(["experiment", "dr-table3", "--quick", "--seeds", "1", "--jobs", "2", "--model", str(model_file),
                     "--out", str(out), "--time-limit", "20"]) == 0
    assert "5/5" in capsys.readouterr().err                       # the progress bar, without -v
    runs = _rows(out / "dr_table3_runs.csv")
    assert [r["cell"] for r in runs] == ["Greedy", "NM_NI", "NM_I", "M_NI", "M_I"]
    assert {"cell", "auction", "strategy", "seed", "objects_done", "within_dl_pct", "within_1.1dl_pct", "late60_pct",
            "utility_soft", "utility_hard", "mean_group", "max_group", "moved_wu", "books_wu", "wall_s"} <= set(runs[0])
    assert {r["auction"] for r in runs} == {"greedy", "sr"} and {r["utility"] for r in runs} == {"hard"}
    objects = _rows(out / "dr_table3_objects.csv")
    assert {"task", "d_m", "appeared_s", "finished_s", "elapsed_s", "t_over_dl", "utility_soft", "utility_hard",
            "mean_group", "max_group"} <= set(objects[0])
    for o in objects:
        assert float(o["utility_hard"]) <= float(o["utility_soft"]) + 1e-9
    md = (out / "dr_table3.md").read_text()
    assert "| Greedy | 30.87 |" in md and "| NM_I | 36.67 |" in md and "Why ours differ" in md
    assert "--model" in md and "commit" in md
    assert (out / "dr_table3_fig3.png").stat().st_size > 5_000
    assert "not the paper's" not in md                            # the quick size's own deadline is not noted ...
    assert C.deadline_note(dr_table3.SETUP) == ""                # ... nor the paper's
    scaled = C.apply_arguments(dr_table3.SETUP, _args(deadline=328.0))
    assert scaled.deadline == 328.0 and "328 s, not the paper's 108 s" in C.deadline_note(scaled)
    assert "3.04 x the paper's 900 tu" in scaled.describe()


def test_dr_table5_quick_writes_its_files(tmp_path, model_file):
    out = tmp_path / "t5"
    assert cli.main(["experiment", "dr-table5", "--quick", "--seeds", "1", "--jobs", "2", "--model", str(model_file),
                     "--out", str(out), "--time-limit", "20"]) == 0
    runs = _rows(out / "dr_table5_runs.csv")
    assert [(r["online"], r["speed_belief"]) for r in runs] == [
        ("False", ""), ("True", ""), ("False", repr(C.ERROR_SPEED)), ("True", repr(C.ERROR_SPEED))]
    assert {r["strategy"] for r in runs} == {"NM_I"} and {r["auction"] for r in runs} == {"dr"}
    assert all(float(r["sim_s"]) == 20.0 for r in runs)
    md = (out / "dr_table5.md").read_text()
    assert "| without errors | 10802 |" in md and "| with errors | 6290 |" in md and "+9.7 %" in md
    assert (out / "dr_table5.png").stat().st_size > 5_000


def test_late_fastest_reaches_every_run_and_the_report(tmp_path, model_file, monkeypatch):
    seen, real = [], C.run_all

    def spy(jobs, *rest):
        seen.extend(cell.late for cell, _, _ in jobs)
        return real(jobs, *rest)

    monkeypatch.setattr(C, "run_all", spy)
    out = tmp_path / "t5"
    assert cli.main(["experiment", "dr-table5", "--quick", "--seeds", "1", "--jobs", "1", "--model", str(model_file),
                     "--out", str(out), "--time-limit", "10", "--late", "fastest"]) == 0
    assert seen == ["fastest"] * 4
    md = (out / "dr_table5.md").read_text()
    assert "`late: fastest`, ours" in md and "--late fastest" in md
    assert C.options(C.Cell("x", late="fastest"), None, C.QUICK).late == "fastest"


def test_online_reaches_the_model_cells_only_and_the_report(tmp_path, model_file, monkeypatch):
    seen, real = [], C.run_all

    def spy(jobs, *rest):
        seen.extend((cell.label, cell.online) for cell, _, _ in jobs)
        return real(jobs, *rest)

    monkeypatch.setattr(C, "run_all", spy)
    out = tmp_path / "t3"
    assert cli.main(["experiment", "dr-table3", "--quick", "--seeds", "1", "--jobs", "1", "--model", str(model_file),
                     "--out", str(out), "--time-limit", "10", "--online"]) == 0
    assert dict(seen) == {"Greedy": False, "NM_NI": False, "NM_I": True, "M_NI": False, "M_I": True}
    md = (out / "dr_table3.md").read_text()
    assert "learns on-line" in md and "--online" in md
    assert {r["cell"]: r["online"] for r in _rows(out / "dr_table3_runs.csv")}["M_I"] == "True"
    with pytest.raises(SystemExit):                 # Table 5's cells are off-line and on-line already
        cli.main(["experiment", "dr-table5", "--quick", "--online", "--out", str(tmp_path / "t5")])


@pytest.mark.slow
def test_dr_table4_quick_writes_its_files(tmp_path, model_file):
    out = tmp_path / "t4"
    assert cli.main(["experiment", "dr-table4", "--quick", "--seeds", "1", "--jobs", "2", "--model", str(model_file),
                     "--out", str(out)]) == 0
    runs = _rows(out / "dr_table4_runs.csv")
    assert len(runs) == 13                       # DR x 4 x {soft, hard}, SR x 4 and Greedy: SR/Greedy serve both
    assert sorted({(r["auction"], r["utility"]) for r in runs}) == [("dr", "hard"), ("dr", "soft"), ("greedy", "soft"),
                                                                    ("sr", "soft")]
    md = (out / "dr_table4.md").read_text()
    assert "| Greedy | 37.88 |" in md and "## Fig. 6: total utility, hard deadline" in md
    for name in ("fig4", "fig5", "fig6"):
        assert (out / f"dr_table4_{name}.png").stat().st_size > 5_000


def _run_row(cell: C.Cell, seed: int, soft: float, hard: float, group: float, within: float) -> dict:
    return {"cell": cell.label, "auction": cell.auction, "strategy": cell.strategy, "seed": seed, "objects_done": 10,
            "within_dl_pct": within, "within_1.1dl_pct": within + 10, "late60_pct": 5.0, "utility_soft": soft,
            "utility_hard": hard, "utility_max": 1000.0, "mean_group": group, "max_group": 4, "mean_time_s": 100.0}


def test_table4_report_computes_gains_over_greedy():
    runs = []
    for seed in (1, 2):
        for cell in dr_table4.CELLS:
            base = 700.0 if cell.auction == "dr" and cell.strategy.endswith("_I") else 500.0
            runs.append(_run_row(cell, seed, base + seed, base - 100 + seed, 3.0 if cell.auction == "greedy" else 2.0, 30))
    soft = {g["strategy"]: g for g in dr_table4.gains(runs, "soft")}
    assert soft["DR NM_I soft"]["ratio"] == pytest.approx(701.5 / 501.5)
    assert soft["DR NM_I soft"]["vs Greedy (paper)"] == "+40 %" and soft["SR NM_I"]["vs Greedy (paper)"] == "-"
    claims = {c[0]: c[3] for c in dr_table4.claims(runs)}
    assert claims["DR soft: M_I and NM_I about 40 % above Greedy"] is True
    assert claims["DR soft: the I strategies above the NI ones"] is True
    assert claims["Greedy puts more robots on an object than DR NM_I"] is True
    assert "| Greedy | 37.88 | 30.0 ± 0.0 | 48.48 | 40.0 ± 0.0 |" in dr_table4.table(runs, (dr_table4.GREEDY,))


def test_a_difference_in_the_noise_is_not_a_claim_that_holds():
    assert C.clearly_more(3.0, 2.0) is True
    assert C.clearly_more(2.7401, 2.7399) is False
    assert C.clearly_more(float("nan"), 2.0) is None


def test_fig3_bins_are_labelled_by_the_edge_nearer_the_deadline():
    labels, share = C.histogram(np.array([-0.25, -0.05, 0.0, 0.05, 0.55, 0.6, 2.0, -3.0]))
    got = dict(zip(labels, share))
    assert got["-0.2"] == got["0"] == got["0.5"] == got["<=-0.9"] == pytest.approx(12.5)
    assert got["-0"] == pytest.approx(25.0)                      # (-0.1, 0]: on time, t <= DL
    assert got[">=0.6"] == pytest.approx(25.0)
    assert sum(share) == pytest.approx(100.0)


def test_pm_is_mean_and_sample_sd():
    assert C.pm([1.0, 3.0]) == "2.0 ± 1.4"
    assert C.pm([float("nan"), 2.0]) == "2.0"                 # one value: no spread to give
    assert C.pm([2.0, 2.0]) == "2.0 ± 0.0"
    assert C.pm([]) == "-"


def test_the_model_is_fitted_from_the_calibration_samples_when_none_is_shipped(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(C, "SHIPPED_MODELS", tmp_path / "none")
    samples = tmp_path / C.CALIBRATION_SAMPLES
    samples.parent.mkdir(parents=True)
    rows = [{"n": n, "d_m": d, "I_wu_per_s": 0.01 * n * n / d} for n in range(1, 9) for d in (1.0, 2.5, 4.0)]
    with samples.open("w", newline="") as fh:
        w = csv.DictWriter(fh, ["n", "d_m", "I_wu_per_s"])
        w.writeheader()
        w.writerows(rows)
    path, source = C.resolve_model(None, tmp_path / "out")
    assert path == (tmp_path / "out" / "model.json").resolve() and "fitted from" in source
    assert len(InterferenceModel.load(path).samples) == 24


@pytest.mark.parametrize("argv, message", [
    (["dr-table3", "--seeds", "0"], "mrta: --seeds 0: expected at least 1"),
    (["dr-table4", "--objects", "0", "--model", "X"], "mrta: --objects 0: expected at least 1"),
    (["dr-table5", "--jobs", "0"], "mrta: --jobs 0: expected at least 1"),
    (["dr-table3", "--time-limit", "-5"], "mrta: --time-limit -5.0: expected seconds > 0"),
    (["dr-table3", "--deadline", "0"], "mrta: --deadline 0.0: expected seconds > 0"),
    (["dr-table3", "--model", "/nonexistent/model.json"], "mrta: /nonexistent/model.json"),
    (["dr-table5"], "mrta: no interference model: expected --model PATH"),
])
def test_bad_options_are_one_line_and_exit_2(argv, message, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)                                   # no results/dr-calibration/samples.csv here
    monkeypatch.setattr(C, "SHIPPED_MODELS", tmp_path / "none")
    assert cli.main(["experiment", *argv, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(message), err
    if "no interference model" in message:
        assert "mrta experiment dr-calibration" in err[0]
