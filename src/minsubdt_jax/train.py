"""Train one method of the table on one dataset, evaluating it in MJX along the way and at the end.

    python -m minsubdt_jax.train --env walker                            # MinSubDT, engineered costs, cpu preset
    python -m minsubdt_jax.train --env walker --method minsubdt-learned  # costs learned from preferences (eq. 3)
    python -m minsubdt_jax.train --env hopper --method dt                # Decision Transformer on the true rewards
    python -m minsubdt_jax.train --env hopper --method bc-mlp            # BC with an MLP (bc: the DT's architecture)
    python -m minsubdt_jax.train --env hopper --preset smoke --eval-every 10 --out /tmp/run
    python -m minsubdt_jax.train --env hopper --out /tmp/run --resume    # continue after an interruption
    python -m minsubdt_jax.train --env hopper --seeds 3                  # seeds 0, 1, 2 as one vmapped program

Several processes (one machine or many; each runs the same command with its own --process-id):

    python -m minsubdt_jax.train --env hopper --num-processes 2 --process-id 0 --coordinator-address localhost:8476 &
    python -m minsubdt_jax.train --env hopper --num-processes 2 --process-id 1 --coordinator-address localhost:8476

The data side is :mod:`minsubdt_jax.pipeline`, the method a record of :mod:`minsubdt_jax.methods`, the learner an
agent of :mod:`minsubdt_jax.agents`, the scoring :mod:`minsubdt_jax.evaluation`. Here: the run. ``--seeds S`` models
train in one jitted ``lax.scan`` chunk (``vmap`` over a leading seed axis), the batch split over every device of
every process (:mod:`minsubdt_jax.parallel`); an orbax checkpoint follows each chunk; every ``--eval-every`` steps
and at the end all seeds are evaluated in one rollout program. The run directory holds ``config.json``,
``dataset.json``, ``metrics.jsonl`` (loss per chunk, evaluations), ``results.json``, ``learning_curve.png`` and
``checkpoints/``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import time
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

from .agents import make_agent
from .agents.base import PolicyInputs, init_seed_states, make_optimizer, make_train_chunk
from .caches import enable_compilation_cache
from .config import Config, parse_args, validate
from .evaluation import across_seeds, evaluate_policy
from .methods import Method, get_method
from .parallel import (assert_same_across_processes, gather, init_distributed, is_main_process, make_mesh, replicate)
from .pipeline import Prepared, prepare
from .references import REFERENCE_SOURCE
from .rundir import (DATASET_FILE, check_run_dir, check_same_data, exit_code, plot_learning_curve, progress,
                     truncate_metrics, write_atomic)

# Fields that may differ between a run and its resumption.
RESUMABLE_CHANGES = ("steps", "eval_episodes", "eval_every", "eval_episodes_periodic", "out", "preset", "devices",
                     "coordinator_address", "num_processes", "process_id")


def train(cfg: Config, resume: bool = False, verbose: bool = True,
          progress_fn: Callable[[int, dict], None] | None = None) -> dict:
    """Run one training job end to end in ``cfg.run_dir()``; returns the contents of ``results.json``.

    ``cfg.seeds`` models (seeds ``cfg.seed ...``) train together; in a multi-process job (``cfg.num_processes``)
    every process calls this, and only process 0 writes the run directory (checkpoints are written jointly by
    orbax). ``progress_fn(step, record)`` (as brax's) receives every record written to ``metrics.jsonl``: the loss
    after each chunk and each evaluation's scores."""
    cfg = validate(cfg)
    method = get_method(cfg.method)
    init_distributed(cfg.coordinator_address, cfg.num_processes, cfg.process_id)
    main = is_main_process()
    verbose = verbose and main
    out = cfg.run_dir()
    ckpt_dir = os.path.abspath(os.path.join(out, "checkpoints"))
    check_run_dir(dataclasses.asdict(cfg), out, ckpt_dir, resume, RESUMABLE_CHANGES)
    mesh = make_mesh(cfg.devices, cfg.batch_size)  # checked before anything is written
    seeds = list(range(cfg.seed, cfg.seed + cfg.seeds))
    # before anything is written: bad data changes nothing. Only learned costs depend on the seed.
    seed_cfgs = [dataclasses.replace(cfg, seed=s) for s in seeds] if method.features == "learned" else [cfg]
    preps = [prepare(c, method, verbose) for c in seed_cfgs]
    data = preps[0].sampler if len(preps) == 1 else jax.tree.map(lambda *x: jnp.stack(x), *[p.sampler for p in preps])
    assert_same_across_processes([np.asarray(x) for x in jax.tree.leaves(data)],
                                 "the training data (every process must load the same dataset)")
    check_same_data(out, preps[0].source.sha256, resume)
    if main:
        os.makedirs(out, exist_ok=True)
        write_atomic(os.path.join(out, "config.json"), cfg.to_json())
        d = preps[0].source
        write_atomic(os.path.join(out, DATASET_FILE), json.dumps(
            {"path": d.path, "sha256": d.sha256, "episodes": d.data.num_trajectories,
             "transitions": d.data.num_transitions}, indent=2))
    dataset = preps[0].source.data
    agent = make_agent(method.agent, cfg, dataset.obs_dim, dataset.act_dim, max(cfg.episode_length, dataset.max_len))
    tx = make_optimizer(cfg)
    state = init_seed_states(agent, tx, seeds)
    mngr = ocp.CheckpointManager(ckpt_dir, options=ocp.CheckpointManagerOptions(max_to_keep=2, create=True))
    if resume and mngr.latest_step() is not None:
        state = mngr.restore(mngr.latest_step(), args=ocp.args.StandardRestore(state))
    start = int(np.asarray(state.step)[0])
    if verbose and resume:
        print(f"resumed from step {start}", flush=True)
    state, data = replicate((state, data), mesh)
    if verbose and (mesh.size > 1 or len(seeds) > 1):
        print(f"{len(seeds)} seed(s) in one program; batch split over {mesh.size} device(s) in "
              f"{jax.process_count()} process(es): {cfg.batch_size // mesh.size} sequences each", flush=True)
    metrics_path = os.path.join(out, "metrics.jsonl")
    if main:
        truncate_metrics(metrics_path, start)

    def log(record):
        if main:
            with open(metrics_path, "a") as f:
                f.write(json.dumps(record) + "\n")
        if progress_fn is not None:
            progress_fn(record["step"], record)

    def evaluate(params, episodes):
        return evaluate_seeds(cfg, method, agent, params, preps, seeds, mesh, episodes)

    chunks = {}
    t0 = time.time()
    step = start
    bar = progress(total=cfg.steps, initial=start, disable=not verbose)
    while step < cfg.steps:
        n = min(cfg.chunk_steps, cfg.steps - step)
        if n not in chunks:
            chunks[n] = make_train_chunk(agent, tx, cfg.batch_size, n, mesh, seed_axis=True,
                                         data_axis=None if len(preps) == 1 else 0)
        tc = time.time()
        state, losses = chunks[n](state, data)
        per_seed = np.asarray(gather(losses)).mean(0)  # [S]
        if not np.isfinite(per_seed).all():
            last = f"the last checkpoint is step {step}" if step else "no checkpoint was written"
            raise ValueError(f"training diverged: non-finite loss {per_seed.tolist()} in steps {step + 1}-{step + n} "
                             f"(not checkpointed; {last}); try a lower --learning-rate")
        step += n
        # records first, checkpoint last: a resumed run drops the records past its checkpoint and redoes them
        log({"step": step, "loss": float(per_seed.mean()), "loss_per_seed": per_seed.tolist(),
             "chunk_seconds": time.time() - tc})
        if cfg.eval_every and step % cfg.eval_every == 0 and step < cfg.steps:
            log(eval_record(step, evaluate(state.params, cfg.eval_episodes_periodic)))
        mngr.save(step, args=ocp.args.StandardSave(state))
        bar.set_postfix(loss=f"{per_seed.mean():.4f}")
        bar.update(n)
    bar.close()
    mngr.wait_until_finished()
    train_seconds = time.time() - t0

    results = {"config": dataclasses.asdict(cfg), "method": {"name": method.name, "label": method.label,
                                                            "agent": method.agent},
               "dataset": preps[0].summary(cfg.env), "references": REFERENCE_SOURCE, "platform": platform(),
               "seeds": seeds, "train": {"steps": step, "steps_this_run": step - start, "seconds_this_run": train_seconds}}
    if len(preps) > 1:
        results["dataset"]["learned_costs_per_seed"] = [p.learned.report for p in preps]
    if cfg.eval_episodes:
        te = time.time()
        per_seed = evaluate(state.params, cfg.eval_episodes)
        results["eval_per_seed"] = per_seed
        results["eval"] = per_seed[0] if len(seeds) == 1 else across_seeds(per_seed)
        results["eval"]["seconds"] = time.time() - te
        log(eval_record(step, per_seed, final=True))
        if verbose:
            e = results["eval"]
            over = "episodes" if len(seeds) == 1 else f"{len(seeds)} seeds"
            print(f"eval: return {e['return_mean']:.1f} ± {e['return_std']:.1f}, normalised "
                  f"{e['normalized_score_mean']:.1f} ± {e['normalized_score_std']:.1f} over {over} "
                  f"({REFERENCE_SOURCE}), min-subdominance {e['min_subdominance_mean']:.3f} "
                  f"(dataset {results['dataset']['min_subdominance_mean']:.3f})")
    if main:
        write_atomic(os.path.join(out, "results.json"), json.dumps(results, indent=2))
        plot_learning_curve(metrics_path, os.path.join(out, "learning_curve.png"))
    if verbose:
        print(f"wrote {out}/results.json", flush=True)
    return results


def evaluate_seeds(cfg: Config, method: Method, agent, params, preps: list[Prepared], seeds: list[int], mesh,
                   episodes: int) -> list[dict]:
    """Evaluate the S trained models (``params [S, ...]``) on ``episodes`` episodes each, in one batched MJX program
    (episodes split over ``mesh``); seed s's episodes are seeded ``s + 10000``. One summary dict per seed."""
    per = [preps[min(i, len(preps) - 1)] for i in range(len(seeds))]  # one prep per seed (shared unless learned)
    stack = lambda get: np.stack([np.asarray(get(p), np.float32) for p in per])  # noqa: E731
    inputs = PolicyInputs(params=params, state_mean=stack(lambda p: p.state_mean),
                          state_std=stack(lambda p: p.state_std), target_return=stack(lambda p: p.target_return),
                          rtg_scale=stack(lambda p: p.rtg_scale),
                          subtract_rewards=np.full(len(seeds), method.subtract_rewards, np.float32))
    learned = [p.learned for p in per] if method.features == "learned" else None
    evs = evaluate_policy(cfg.env, agent, replicate(inputs, mesh), num_episodes=episodes, horizon=cfg.episode_length,
                          seeds=[s + 10_000 for s in seeds], demo_costs=per[0].costs, beta=cfg.beta,
                          alpha_max=cfg.alpha_max, learned=learned,
                          demo_features=[p.features for p in per] if learned else None, mesh=mesh)
    return [dict(ev.summary(), seed=s, target_return=p.target_return) for ev, s, p in zip(evs, seeds, per)]


def eval_record(step: int, per_seed: list[dict], final: bool = False) -> dict:
    """The ``metrics.jsonl`` record of one evaluation: per-seed normalised score, min-subdominance and return."""
    rec = {"step": step, "eval_episodes": per_seed[0]["episodes"], "final": final}
    for key in ("normalized_score", "min_subdominance", "return"):
        rec[f"eval_{key}"] = [e[f"{key}_mean"] for e in per_seed]
    return rec


def platform() -> dict:
    """What the run ran on (results are compared only within one platform)."""
    dev = jax.devices()[0]
    return {"backend": jax.default_backend(), "device": dev.device_kind, "devices": jax.device_count(),
            "processes": jax.process_count(), "jax": jax.__version__}


def main(argv=None) -> int:
    enable_compilation_cache()
    return exit_code(lambda: train(*parse_args(argv)))


if __name__ == "__main__":
    sys.exit(main())
