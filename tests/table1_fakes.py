"""What tests/test_table1*.py share: a fake trainer's results, laid out as ``minsubdt_jax.train`` writes them (the
``table1`` fixture, experiments/table1.py, is conftest's)."""

import dataclasses

from minsubdt_jax.agents.dt.networks import DT_REVISION

BASE = {"awr": 10.0, "minsubdt": 50.0, "minsubdt-learned": 40.0, "dt": 60.0, "bc": 30.0, "cql": 20.0, "iql": 55.0,
        "minsubdt-iql": 45.0}


def fake_results(cfg):
    """``train``'s results for ``cfg.datasets`` x ``cfg.methods`` x ``cfg.seeds`` models, laid out as the real one
    writes them (a dataset's score is offset by 100 x its index)."""
    seeds = list(range(cfg.seed, cfg.seed + cfg.seeds))
    many = len(cfg.datasets) > 1
    models = [(m, s) for m in cfg.methods for s in seeds]
    evals = [{"method": m, "seed": s, "normalized_score_mean": BASE[m] + s + 100 * i,
              "better_than_mean_demo_share": 0.5 + 0.1 * s, "min_subdominance_mean": 1.0, "episodes": 2,
              "length_mean": 600.0 + 100 * s,
              "costs": [[0.4, 0.5], [0.6, 0.4]], **({"dataset": d} if many else {})}
             for i, d in enumerate(cfg.datasets) for m, s in models]
    models = [m for _ in cfg.datasets for m in models]
    data = [{"normalized_score_mean": 45.0, "min_subdominance_mean": 1.5,
             "costs_mean": {"x_velocity": 0.5, "z_velocity": 0.5},
             "spearman_neg_min_subdominance_vs_return": 0.9 if m == "minsubdt" else 0.7,
             "learned_costs": {"heldout_pair_accuracy": 0.8 + 0.01 * s}} for m, s in models]
    res = {"config": dataclasses.asdict(cfg), "seeds": seeds,
           "models": [{k: e[k] for k in ("dataset", "method", "seed") if k in e} for e in evals],
           "dataset": dict(data[0], costs_sample=[[0.5, 0.5]]), "train": {"steps": 1}, "eval_per_model": evals,
           "dt_revision": DT_REVISION}
    if len(models) > 1:
        res["dataset_per_model"] = data
    return res


def recording_sweep(tmp_path):
    """``(calls, kw)``: ``run_sweep`` keywords for hopper medium at smoke whose fake training records
    ``(method, seed, seeds)`` in ``calls``."""
    calls = []

    def fake_train(cfg, resume=False, verbose=False):
        calls.append((cfg.method, cfg.seed, cfg.seeds))
        return fake_results(cfg)

    return calls, dict(preset="smoke", envs=("hopper",), datasets=("medium",), runs_root=str(tmp_path / "runs"),
                       results_root=str(tmp_path / "res"), train_fn=fake_train, log=lambda *_: None)
