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
    """``train``'s results for ``cfg.seeds`` seeds from ``cfg.seed`` (per-seed lists as the real one writes)."""
    seeds = list(range(cfg.seed, cfg.seed + cfg.seeds))
    evals = [{"seed": s, "normalized_score_mean": {"minsubdt": 50.0, "minsubdt-learned": 40.0, "dt": 60.0, "bc": 30.0}
              [cfg.method] + s, "better_than_mean_demo_share": 0.5 + 0.1 * s, "min_subdominance_mean": 1.0,
              "costs": [[0.4, 0.5], [0.6, 0.4]]} for s in seeds]
    res = {"config": {"env": cfg.env, "dataset": cfg.dataset, "method": cfg.method, "seed": cfg.seed,
                      "seeds": cfg.seeds}, "seeds": seeds,
           "dataset": {"normalized_score_mean": 45.0, "min_subdominance_mean": 1.5, "costs_sample": [[0.5, 0.5]],
                       "costs_mean": {"x_velocity": 0.5, "z_velocity": 0.5},
                       "spearman_neg_min_subdominance_vs_return": 0.9 if cfg.method == "minsubdt" else 0.7,
                       "learned_costs": {"heldout_pair_accuracy": 0.8}},
           "train": {"steps": 1}, "eval_per_seed": evals,
           "eval": evals[0] if len(seeds) == 1 else {"normalized_score_mean": -1.0}}  # across seeds: unused
    if cfg.method == "minsubdt-learned" and len(seeds) > 1:
        res["dataset"]["learned_costs_per_seed"] = [{"heldout_pair_accuracy": 0.8 + 0.01 * s} for s in seeds]
    return res


def test_seed_runs_groups_consecutive_seeds(table1):
    assert table1.seed_runs([2, 0, 1]) == [(0, 3)]
    assert table1.seed_runs({0, 2, 3, 5}) == [(0, 1), (2, 2), (5, 1)]
    assert table1.seed_runs([]) == []


def test_sweep_skips_finished_runs_and_aggregates_partial_results(table1, tmp_path):
    calls = []

    def fake_train(cfg, resume=False, verbose=False):
        calls.append((cfg.env, cfg.dataset, cfg.method, cfg.seed, cfg.seeds, os.path.basename(cfg.out)))
        if cfg.method == "bc" and cfg.seed + cfg.seeds > 1:  # any program that trains seed 1 of BC
            raise RuntimeError("simulated crash")
        return fake_results(cfg)

    kw = dict(preset="smoke", envs=("hopper",), datasets=("medium",), runs_root=str(tmp_path / "runs"),
              results_root=str(tmp_path / "res"), train_fn=fake_train, log=lambda *_: None)
    st = table1.run_sweep(methods=("minsubdt", "bc"), seeds=(0,), **kw)
    assert calls == [("hopper", "medium", "minsubdt", 0, 1, "hopper-medium-minsubdt-s0"),
                     ("hopper", "medium", "bc", 0, 1, "hopper-medium-bc-s0")] and len(st["done"]) == 2
    calls.clear()
    st = table1.run_sweep(methods=("minsubdt", "bc", "minsubdt-learned"), seeds=(0, 1, 2), **kw)
    # finished seeds are skipped; a cell's missing consecutive seeds are one --seeds program; lowest seed first
    assert calls == [("hopper", "medium", "minsubdt-learned", 0, 3, "hopper-medium-minsubdt-learned-s0-2"),
                     ("hopper", "medium", "minsubdt", 1, 2, "hopper-medium-minsubdt-s1-2"),
                     ("hopper", "medium", "bc", 1, 2, "hopper-medium-bc-s1-2")]
    assert len(st["skipped"]) == 2 and st["failed"] == ["hopper-medium-bc-s1", "hopper-medium-bc-s2"]
    calls.clear()
    st = table1.run_sweep(methods=("minsubdt", "bc", "minsubdt-learned", "dt"), seeds=(0, 1), **kw)
    # the failed program is retried (for the seeds asked now), the new method trained
    assert calls == [("hopper", "medium", "dt", 0, 2, "hopper-medium-dt-s0-1"),
                     ("hopper", "medium", "bc", 1, 1, "hopper-medium-bc-s1")]
    assert len(st["skipped"]) == 5 and st["failed"] == ["hopper-medium-bc-s1"]
    # a multi-seed program's files read as that seed's single run, its own learned-cost report included
    res_dir = tmp_path / "res" / "table1" / "smoke"
    r2 = json.loads((res_dir / "hopper-medium-minsubdt-learned-s2.json").read_text())
    assert r2["config"]["seed"] == 2 and r2["config"]["seeds"] == 1 and r2["eval"]["normalized_score_mean"] == 42.0
    assert r2["dataset"]["learned_costs"]["heldout_pair_accuracy"] == pytest.approx(0.82)
    assert "learned_costs_per_seed" not in r2["dataset"] and "eval_per_seed" not in r2

    out = table1.aggregate("smoke", results_root=str(tmp_path / "res"), out_root=str(tmp_path / "agg"), plots=True)
    cell = out["table"]["medium/hopper"]
    assert cell["minsubdt"]["mean"] == pytest.approx(51.0) and cell["minsubdt"]["std"] == pytest.approx(np.std([0, 1, 2]))
    assert cell["minsubdt"]["n_seeds"] == 3 and cell["bc"]["n_seeds"] == 1 and cell["bc"]["mean"] == 30.0
    assert cell["dt"]["better_than_mean_demo_share"] == pytest.approx(0.55)
    assert cell["minsubdt-learned"]["n_seeds"] == 3 and cell["minsubdt-learned"]["mean"] == pytest.approx(41.0)
    av = out["averages"]["all"]
    assert av["minsubdt"]["cells"] == 1 and av["minsubdt"]["of"] == 9
    md = (tmp_path / "agg" / "table1.md").read_text()
    assert out["cost_rank_agreement"]["medium/hopper"]["engineered_spearman"] == 0.9
    assert "51.0 ± 0.8 (3)" in md and "30.0 ± 0.0 (1)" in md and "Published" in md
    assert (tmp_path / "agg" / "table1_costs_hopper.png").exists()
    assert json.loads((tmp_path / "agg" / "table1.json").read_text())["runs"] == 9
    # every result file is complete JSON (written atomically)
    files = os.listdir(res_dir)
    assert len(files) == 9 and not any(f.endswith(".tmp") for f in files)
    assert np.isclose(json.loads((res_dir / "hopper-medium-dt-s1.json").read_text())
                      ["eval"]["normalized_score_mean"], 61.0)
