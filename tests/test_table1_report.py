"""experiments/table1.py's report: each cell's training curves, MinSubDT against DT by Welch's difference, and the
table before the DT fix beside today's (a fake trainer)."""

import json
import os

import numpy as np
import pytest

from table1_fakes import BASE, fake_results


def test_report_draws_each_cells_training_curves(table1, tmp_path, monkeypatch):
    """``aggregate`` plots each landed cell from its result files' curves, else from its run directories (and only
    that cell's: walker-medium-replay runs are not walker medium's) with minsubdt_jax.plot; a cell still training
    gets no figure, a landed cell trained on another machine keeps its committed one, and the report links them."""
    import minsubdt_jax.plot as plot
    import table1_figures

    drawn, plot_runs = [], plot.plot_runs
    monkeypatch.setattr(plot, "plot_runs", lambda dirs, *a, **k: (drawn.extend(dirs), plot_runs(dirs, *a, **k)))
    runs = tmp_path / "runs" / "smoke"
    for name in ("walker-medium-minsubdt+dt-s0-1", "walker-medium-replay-dt-s0", "walker-medium-bc-s0",
                 "walker-medium-expert-dt-s1"):  # the last: one seed of a cell whose result files hold all
        (runs / name).mkdir(parents=True)
        recs = [{"step": 10, "loss": 1.0, "loss_per_model": [1.0]},
                {"step": 10, "final": True, "eval_method": ["dt"], "eval_seed": [0], "eval_normalized_score": [40.0],
                 "eval_min_subdominance": [1.0]}]
        (runs / name / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
    agg = tmp_path / "agg"
    (agg / "table1_curves").mkdir(parents=True)
    (agg / "table1_curves" / "smoke-hopper-medium.png").write_bytes(b"committed")  # landed, trained elsewhere
    # a program of two models (dt s0, bc s1): each result file keeps its own model's curve
    prog = tmp_path / "runs" / "elsewhere"
    prog.mkdir()
    recs = [{"step": 5, "loss": 2.0, "loss_per_model": [3.0, 1.0]},
            {"step": 5, "eval_method": ["dt", "bc"], "eval_seed": [0, 1], "eval_normalized_score": [10.0, 20.0],
             "eval_min_subdominance": [1.0, 2.0]},
            {"step": 10, "loss": 1.0, "loss_per_model": [1.5, 0.5]},
            {"step": 10, "final": True, "eval_method": ["dt", "bc"], "eval_seed": [0, 1],
             "eval_normalized_score": [30.0, 40.0], "eval_min_subdominance": [0.5, 1.5]}]
    (prog / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
    bc = table1_figures.model_curve(str(prog), {"method": "bc", "seed": 1})
    assert bc == {"step": [5, 10], "final": [False, True], "normalized_score": [20.0, 40.0],
                  "min_subdominance": [2.0, 1.5], "loss_step": [5, 10], "loss": [1.0, 0.5]}
    assert table1_figures.model_curve(str(tmp_path), {"method": "bc", "seed": 1}) is None  # no evaluations there
    with pytest.raises(ValueError, match="evaluates no model"):
        table1_figures.model_curve(str(prog), {"method": "bc", "seed": 0})
    rows = [{"env": "walker", "dataset": "medium-expert", "method": m, "seed": s,
             "r": {"curve": dict(bc, normalized_score=[v, v + 10.0])}} for m, s, v in (("dt", 0, 0.0), ("dt", 1, 4.0))]
    c = table1_figures.curves_from_results(rows)
    np.testing.assert_allclose(c["score"]["dt"][1], [2.0, 12.0])
    np.testing.assert_allclose(c["score"]["dt"][2], [2.0, 2.0])
    # a critic agent's program in the same cell evaluates and logs its loss at other steps: its own group
    iql = dict(bc, step=[50, 100], final=[False, True], loss_step=[50, 100])
    rows.append({"env": "walker", "dataset": "medium-expert", "method": "iql", "seed": 0, "r": {"curve": iql}})
    assert {k: [(r["method"], r["seed"]) for r in g] for k, g in table1_figures.programs_of(rows).items()} == {
        "dt": [("dt", 0), ("dt", 1)], "iql": [("iql", 0)]}
    other = [{"env": "walker", "dataset": "medium-expert", "method": "iql", "seed": 1,
              "r": {"curve": dict(iql, step=[60, 120], loss_step=[60, 120])}}]  # the same method, another schedule
    assert {k: [r["seed"] for r in g] for k, g in table1_figures.programs_of(rows + other).items()} == {
        "dt": [0, 1], "iql": [0], "iql (evaluated at [60, 120])": [1]}
    with pytest.raises(ValueError, match="programs_of"):
        table1_figures.curves_from_results(rows)
    landed = {"medium/walker", "medium/hopper", "medium-expert/hopper", "medium-expert/walker"}
    pngs = table1_figures.plot_cell_curves("smoke", str(tmp_path / "runs"), str(agg), landed, rows)
    assert pngs == {"medium/walker": "table1_curves/smoke-walker-medium.png",
                    "medium/hopper": "table1_curves/smoke-hopper-medium.png",
                    "medium-expert/walker": "table1_curves/smoke-walker-medium-expert.png"}  # from its result files
    assert sorted(os.path.basename(d) for d in drawn) == ["walker-medium-bc-s0", "walker-medium-minsubdt+dt-s0-1"]
    assert (agg / pngs["medium/walker"]).stat().st_size > 1000
    assert (agg / pngs["medium-expert/walker"]).stat().st_size > 1000
    assert not (agg / "table1_curves" / "smoke-walker-medium-replay.png").exists()


def test_versus_dt_is_welchs_difference_with_a_two_se_verdict(table1):
    from scipy.stats import ttest_ind

    scores = {"medium/hopper": {"minsubdt": [40.0, 42.0, 47.0], "minsubdt-learned": [50.0, 55.0, 52.0],
                                "dt": [50.0, 50.0, 53.0]},
              "medium/walker": {"minsubdt": [30.0, 60.0], "dt": [10.0]}, "medium-replay/hopper": {"bc": [1.0, 2.0]}}
    table = {k: {m: {"mean": float(np.mean(s)), "std": float(np.std(s)), "n_seeds": len(s),
                     "better_than_mean_demo_share": 0.5, "rollout_min_subdominance": 1.0} for m, s in row.items()}
             for k, row in scores.items()}
    vs = table1.versus_dt(table)
    for m in ("minsubdt", "minsubdt-learned"):  # Welch's t is diff / se; its p has Welch-Satterthwaite's dof
        ref = ttest_ind(scores["medium/hopper"][m], scores["medium/hopper"]["dt"], equal_var=False)
        v = vs["medium/hopper"][m]
        assert v["diff"] / v["se"] == pytest.approx(ref.statistic, rel=1e-12)
        assert (v["df"], v["p"]) == pytest.approx((ref.df, ref.pvalue), rel=1e-9)
    assert vs["medium/hopper"]["minsubdt"]["diff"] == pytest.approx(-8.0)
    assert vs["medium/hopper"]["minsubdt"]["verdict"] == "behind"  # t = -3.5
    assert vs["medium/hopper"]["minsubdt-learned"]["verdict"] == "level"  # t = 0.8
    assert vs["medium/walker"] == {"minsubdt": {"diff": 35.0, "se": None, "df": None, "p": None,
                                                "verdict": "–"}}  # DT has 1 seed
    assert "medium-replay/hopper" not in vs
    flat = {"mean": 100.0, "std": 0.0, "n_seeds": 2}  # no spread in either column: no test, the 2 SE verdict stands
    assert table1.versus_dt({"m/e": {"minsubdt": flat, "dt": dict(flat, mean=90.0)}})["m/e"]["minsubdt"] == {
        "diff": 10.0, "se": 0.0, "df": None, "p": None, "verdict": "ahead"}
    md = table1.markdown({"preset": "study", "table": table, "averages": {}, "dataset_score": {},
                          "cost_rank_agreement": {}})
    assert "| medium | hopper | -8.0 ± 2.3: behind (p 0.04) | +1.3 ± 1.8: level (p 0.50) |" in md
    assert "behind DT in 1 of 1 cells with ≥ 2 seeds each: hopper medium (-8.0)" in md
    assert "without a result at `study` (every cell '–'): CQL, BEAR, BRAC-v, AWR, IQL, TD3+BC." in md
    # the header says what a preset's numbers are: study's setting, paper's as they are, any other not a result
    heads = {p: table1.markdown({"preset": p, "table": table, "averages": {}, "dataset_score": {},
                                 "cost_rank_agreement": {}}).split("| dataset |")[0] for p in ("study", "paper", "cpu")}
    assert "The `study` preset:" in heads["study"] and "Not a result" not in heads["study"]
    assert "The `study` preset:" not in heads["paper"] and "Not a result" not in heads["paper"]
    assert "**Not a result**: the `cpu` preset" in heads["cpu"]


def test_report_puts_the_table_before_the_dt_fix_beside_todays(table1, tmp_path):
    """Issue 54: where ``table1/<preset>-dt-rev1/`` keeps the DT-family results of the model before the fix, the
    report shows each cell's earlier mean beside today's with the change, the averages, and both verdicts."""
    import shutil

    kw = dict(preset="smoke", envs=("hopper",), datasets=("medium",), runs_root=str(tmp_path / "runs"),
              results_root=str(tmp_path / "res"), train_fn=lambda cfg, **_: fake_results(cfg), log=lambda *_: None)
    table1.run_sweep(methods=("minsubdt", "dt"), seeds=(0, 1), **kw)
    res = tmp_path / "res" / "table1"
    shutil.copytree(res / "smoke", res / "smoke-dt-rev1")
    for f in (res / "smoke-dt-rev1").glob("*-dt-s*.json"):  # the earlier DT 7 points lower
        r = json.loads(f.read_text())
        r["eval"]["normalized_score_mean"] -= 7.0
        f.write_text(json.dumps(r))
    out = table1.aggregate("smoke", results_root=str(tmp_path / "res"), out_root=str(tmp_path / "agg"), plots=False)
    md = (tmp_path / "agg" / "table1.md").read_text()
    assert out["before_dt_fix"]["table"]["medium/hopper"]["dt"] == BASE["dt"] + 0.5 - 7.0
    assert "## Before the DT fix" in md
    assert f"| medium | hopper | {BASE['minsubdt'] + 0.5:.1f} → {BASE['minsubdt'] + 0.5:.1f} (+0.0) | – | " \
           f"{BASE['dt'] - 6.5:.1f} → {BASE['dt'] + 0.5:.1f} (+7.0) | – |" in md
    assert "| medium | hopper | behind → behind | – → – |" in md  # MinSubDT below DT in both tables
    # the fake data scores 45.0: MinSubDT (50.5) is above it in the one cell of each table; no BC column was trained
    assert "MinSubDT (engg. costs): above the data in 1 of 1 cells, above BC in 0 (earlier: 1 and 0 of 1)." in md


def test_before_the_fix_averages_compare_the_same_cells(table1, tmp_path):
    """While the rerun lands cell by cell, an average before the fix is taken over the cells rerun so far, not over
    every earlier cell (a 1-cell average beside a 9-cell one read as a +38 change)."""
    import shutil

    kw = dict(preset="smoke", envs=("hopper",), datasets=("medium", "medium-replay"), runs_root=str(tmp_path / "runs"),
              results_root=str(tmp_path / "res"), train_fn=lambda cfg, **_: fake_results(cfg), log=lambda *_: None)
    table1.run_sweep(methods=("dt",), seeds=(0, 1), **kw)
    res = tmp_path / "res" / "table1"
    shutil.copytree(res / "smoke", res / "smoke-dt-rev1")
    for f in (res / "smoke-dt-rev1").glob("*.json"):  # earlier: medium 7 points lower, medium-replay 30
        r = json.loads(f.read_text())
        r["eval"]["normalized_score_mean"] -= 30.0 if "medium-replay" in f.name else 7.0
        f.write_text(json.dumps(r))
    for f in (res / "smoke").glob("hopper-medium-replay-*.json"):
        f.unlink()  # today: medium only
    table1.aggregate("smoke", results_root=str(tmp_path / "res"), out_root=str(tmp_path / "agg"), plots=False)
    md = (tmp_path / "agg" / "table1.md").read_text().split("## Before the DT fix")[1]
    now = BASE["dt"] + 0.5
    assert f"| **average (all)** | | – | – | {now - 7:.1f} → {now:.1f} (+7.0), 1 of 2 cells | – |" in md
    assert f"| **average (without medium-replay)** | | – | – | {now - 7:.1f} → {now:.1f} (+7.0) | – |" in md


def test_report_lists_each_seeds_score_length_and_recording(table1, tmp_path):
    """Each DT-family run's own score and rollout length, by seed, beside the recording it trained on: the table
    gives mean ± std only, and the seeds of one cell may come from different recordings of the recipe."""
    kw = dict(preset="smoke", envs=("hopper",), datasets=("medium",), runs_root=str(tmp_path / "runs"),
              results_root=str(tmp_path / "res"), train_fn=lambda cfg, **_: fake_results(cfg), log=lambda *_: None)
    table1.run_sweep(methods=("minsubdt", "dt"), seeds=(0, 1), **kw)
    for f in (tmp_path / "res" / "table1" / "smoke").glob("*-s1.json"):  # seed 1 on another file, own score 47.0
        r = json.loads(f.read_text())
        r["dataset"].update(sha256="b" * 64, normalized_score_mean=47.0)
        f.write_text(json.dumps(r))
    table1.aggregate("smoke", results_root=str(tmp_path / "res"), out_root=str(tmp_path / "agg"), plots=False)
    md = (tmp_path / "agg" / "table1.md").read_text().split("## Each seed")[1].split("\n## ")[0]
    # fake_results: score BASE[m] + seed, length 600 + 100 x seed; no BC or learned-cost run
    assert "| medium | hopper | 0 | not recorded (45.0) | 50.0 (600) | – | 60.0 (600) | – |" in md
    assert "| medium | hopper | 1 | bbbbbbbbbbbb (47.0) | 51.0 (700) | – | 61.0 (700) | – |" in md
    assert "| medium | walker |" not in md  # cells without a run have no row
