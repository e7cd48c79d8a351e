"""experiments/table1.py: skipping finished runs and aggregating partial results (a fake trainer)."""

import importlib.util
import json
import os

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture(scope="module")
def table1():
    spec = importlib.util.spec_from_file_location("table1", os.path.join(ROOT, "experiments", "table1.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def fake_results(cfg):
    score = {"subdom": 50.0, "learned": 40.0, "true": 60.0, "none": 30.0}[cfg.returns] + cfg.seed
    return {"config": {"env": cfg.env, "dataset": cfg.dataset, "returns": cfg.returns, "seed": cfg.seed},
            "dataset": {"normalized_score_mean": 45.0, "min_subdominance_mean": 1.5, "costs_sample": [[0.5, 0.5]],
                        "costs_mean": {"x_velocity": 0.5, "z_velocity": 0.5},
                        "spearman_neg_min_subdominance_vs_return": 0.9 if cfg.returns == "subdom" else 0.7,
                        "learned_costs": {"heldout_pair_accuracy": 0.8}},
            "train": {"steps": 1},
            "eval": {"normalized_score_mean": score, "better_than_mean_demo_share": 0.5 + 0.1 * cfg.seed,
                     "min_subdominance_mean": 1.0, "costs": [[0.4, 0.5], [0.6, 0.4]]}}


def test_sweep_skips_finished_runs_and_aggregates_partial_results(table1, tmp_path):
    calls = []

    def fake_train(cfg, resume=False, verbose=False):
        calls.append((cfg.env, cfg.dataset, cfg.returns, cfg.seed))
        if cfg.returns == "none" and cfg.seed == 1:
            raise RuntimeError("simulated crash")
        return fake_results(cfg)

    kw = dict(preset="smoke", envs=("hopper",), datasets=("medium",), runs_root=str(tmp_path / "runs"),
              results_root=str(tmp_path / "res"), train_fn=fake_train, log=lambda *_: None)
    st = table1.run_sweep(methods=("subdom", "none"), seeds=(0, 1), **kw)
    assert len(calls) == 4 and st["failed"] == ["hopper-medium-none-s1"] and len(st["done"]) == 3
    # seed 0 of every cell comes first
    assert [c[3] for c in calls] == [0, 0, 1, 1]
    calls.clear()
    st = table1.run_sweep(methods=("subdom", "none", "true"), seeds=(0, 1), **kw)
    # finished runs are skipped; the failed one and the new method are (re)tried
    assert sorted(calls) == sorted([("hopper", "medium", "none", 1), ("hopper", "medium", "true", 0),
                                    ("hopper", "medium", "true", 1)])
    assert len(st["skipped"]) == 3 and st["failed"] == ["hopper-medium-none-s1"]

    out = table1.aggregate("smoke", results_root=str(tmp_path / "res"), out_root=str(tmp_path / "agg"), plots=True)
    cell = out["table"]["medium/hopper"]
    assert cell["subdom"]["mean"] == pytest.approx(50.5) and cell["subdom"]["std"] == pytest.approx(0.5)
    assert cell["subdom"]["n_seeds"] == 2 and cell["none"]["n_seeds"] == 1 and cell["none"]["mean"] == 30.0
    assert cell["true"]["better_than_mean_demo_share"] == pytest.approx(0.55)
    assert "learned" not in cell
    av = out["averages"]["all"]
    assert av["subdom"]["cells"] == 1 and av["subdom"]["of"] == 9 and av["learned"]["mean"] is None
    md = (tmp_path / "agg" / "table1.md").read_text()
    assert out["cost_rank_agreement"]["medium/hopper"]["engineered_spearman"] == 0.9
    assert "50.5 ± 0.5 (2)" in md and "30.0 ± 0.0 (1)" in md and "Published" in md
    assert (tmp_path / "agg" / "table1_costs_hopper.png").exists()
    assert json.loads((tmp_path / "agg" / "table1.json").read_text())["runs"] == 5
    # every result file is complete JSON (written atomically)
    files = os.listdir(tmp_path / "res" / "table1" / "smoke")
    assert len(files) == 5 and not any(f.endswith(".tmp") for f in files)
    assert np.isclose(json.loads((tmp_path / "res" / "table1" / "smoke" / "hopper-medium-true-s1.json").read_text())
                      ["eval"]["normalized_score_mean"], 61.0)
