"""A training run's evaluations and its results: the periodic evaluation's record, the final evaluation (per model
and per method over its seeds) and ``results.json`` with the learning-curve plot (:func:`finish_run`)."""

from __future__ import annotations

import dataclasses
import os
import time

import jax

from .agents.base import eval_params
from .agents.dt.networks import DT_REVISION
from .config import PRESETS
from .envs import physics_record
from .scoring import across_seeds
from .program import eval_record, evaluate_models
from .plot import plot_learning_curve
from .rundir import json_text, write_atomic
from .runsetup import ModelData, RunPlan, Started, Trained

METRICS_FILE_JSONL = "metrics.jsonl"  # the run's record: a line per chunk (its loss) and per evaluation


def evaluate_run_models(run: RunPlan, agent, params, per_model, episodes: int) -> list[dict]:
    return evaluate_models(run.cfg, agent, params, run.models, per_model, run.mesh, episodes, physics=run.physics,
                           dynamics=run.dynamics)


def periodic_eval(run: RunPlan, agent, state, step: int, per_model) -> dict:
    """The record of a periodic evaluation; with a moving average, the raw parameters' scores beside (``eval_raw_``)."""
    episodes = run.cfg.eval_episodes_periodic
    rec = eval_record(step, evaluate_run_models(run, agent, eval_params(state), per_model, episodes))
    if state.ema_params is not None:
        raw = eval_record(step, evaluate_run_models(run, agent, state.params, per_model, episodes))
        rec.update({k.replace("eval_", "eval_raw_", 1): v for k, v in raw.items()
                    if k.startswith("eval_") and k not in ("eval_episodes", "eval_method", "eval_seed")})
    return rec


def finish_run(run: RunPlan, started: Started, trained: Trained, models: ModelData, log, loggers) -> dict:
    """The final evaluation, ``results.json`` and the learning-curve plot; the results' dictionary."""
    cfg, methods, preps, per_model = run.cfg, run.methods, models.preps, models.per_model
    agent, state, step, start, seconds = started.agent, trained.state, trained.step, started.start, trained.seconds
    describe = lambda m: {"name": m.name, "label": m.label, "agent": m.agent}  # noqa: E731
    summaries = {id(p): p.summary(cfg.env) for p in preps.values()}  # once per prepared data, not per model
    own = [summaries[id(p)] for p in per_model]
    results = {"config": dataclasses.asdict(cfg), "dataset": own[0],
               "references": per_model[0].references.record(),
               "physics": {**physics_record(run.physics, run.dynamics, cfg.physics_threads),
                           "dynamics_from": run.dynamics_how},
               "platform": platform(), "seeds": list(range(cfg.seed, cfg.seed + cfg.seeds)),
               "dt_revision": DT_REVISION, "models": [mo.record() for mo in run.models],
               "train": {"steps": step, "steps_this_run": step - start, "seconds_this_run": seconds}}
    results.update({"method": describe(methods[0])} if len(methods) == 1 else {"methods": [describe(m) for m in methods]})
    if len(preps) > 1:  # the models' own data summaries (min-subdominance on their features, learned costs)
        results["dataset_per_model"] = [{k: v for k, v in d.items() if k != "costs_sample" or len(cfg.datasets) > 1}
                                        for d in own]
    if cfg.eval_episodes:
        _final_eval(run, agent, state, step, per_model, own, results, log)
    if run.main:
        loggers.close()
        write_atomic(os.path.join(run.out, "results.json"), json_text(results, indent=2))
        plot_learning_curve(os.path.join(run.out, METRICS_FILE_JSONL), os.path.join(run.out, "learning_curve.png"),
                            f"{cfg.env} {cfg.dataset}: {cfg.method} ({cfg.seeds} seed{'s' * (cfg.seeds > 1)})")
    if run.verbose:
        print(f"wrote {run.out}/results.json", flush=True)
        if cfg.preset == "quick":
            study = PRESETS["study"]
            print(f"This was a quick run (the default preset, quick: {cfg.steps} steps, {cfg.eval_episodes} evaluation "
                  f"episodes). Table 1's setting is --preset study ({study.steps // 1000}k steps, "
                  f"{study.eval_episodes} episodes; critic agents their own), "
                  f"e.g. python -m minsubdt_jax.train --env {cfg.env} --dataset {cfg.dataset} --method {cfg.method} "
                  f"--preset study --seeds 3", flush=True)
    return results


def _final_eval(run: RunPlan, agent, state, step: int, per_model, own: list, results: dict, log) -> None:
    """The final evaluation on ``cfg.eval_episodes`` per model into ``results`` (per model, and per method: over its
    seeds), logged and printed."""
    cfg, te = run.cfg, time.time()
    per = evaluate_run_models(run, agent, eval_params(state), per_model, cfg.eval_episodes)
    results["eval_per_model"] = per  # one entry per model (its method and seed inside)
    name_of = lambda e: e["method"] if len(cfg.datasets) == 1 else f"{e['dataset']}/{e['method']}"  # noqa: E731
    by_method = {}  # method (dataset/method over several datasets) -> its models' indices
    for i, e in enumerate(per):
        by_method.setdefault(name_of(e), []).append(i)
    summary = {k: per[v[0]] if len(v) == 1 else across_seeds([per[i] for i in v]) for k, v in by_method.items()}
    for v in summary.values():
        v["seconds"] = time.time() - te
    if len(summary) == 1:
        results["eval"] = summary[run.methods[0].name]
    else:
        results["eval_by_method"] = summary
    log(eval_record(step, per, final=True))
    for name, e in summary.items() if run.verbose else ():
        demo = own[by_method[name][0]]
        over = (f"{cfg.eval_episodes} episodes" if cfg.seeds == 1
                else f"{cfg.seeds} seeds x {cfg.eval_episodes} episodes")
        print(f"eval {name}: return {e['return_mean']:.1f} ± {e['return_std']:.1f}, normalised "
              f"{e['normalized_score_mean']:.1f} ± {e['normalized_score_std']:.1f} over {over} "
              f"({per_model[by_method[name][0]].references.source}), min-subdominance {e['min_subdominance_mean']:.3f} "
              f"(dataset {demo['min_subdominance_mean']:.3f})")
        demo = demo["costs_mean"]
        print("  costs (lower is better; demos' mean): " + ", ".join(
            f"{k} {v:.3f} ({demo[k]:.3f})" if k in demo else f"{k} {v:.3f}" for k, v in e["costs_mean"].items())
            + f"; dominate the mean demo (no metric worse, one better): {100 * e['better_than_mean_demo_share']:.0f} %")


def platform() -> dict:
    """What the run ran on (results are compared only within one platform)."""
    dev = jax.devices()[0]
    return {"backend": jax.default_backend(), "device": dev.device_kind, "devices": jax.device_count(),
            "processes": jax.process_count(), "jax": jax.__version__}
