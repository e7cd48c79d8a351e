"""Train a Minimally Subdominant Decision Transformer (or a DT, or BC) and evaluate it in MJX.

    python -m minsubdt_jax.train --env walker                       # cpu preset, surrogate returns
    python -m minsubdt_jax.train --env walker --returns learned     # costs learned from preferences (eq. 3)
    python -m minsubdt_jax.train --env hopper --returns true        # plain DT on the true rewards
    python -m minsubdt_jax.train --env hopper --returns none        # BC: the same transformer, return tokens 0
    python -m minsubdt_jax.train --env hopper --preset smoke --out /tmp/run
    python -m minsubdt_jax.train --env hopper --out /tmp/run --resume   # continue after an interruption

Pipeline: dataset -> engineered (or learned) cost features -> min-subdominance (eq. 2, leave-one-out) -> surrogate
returns-to-go -> DT training (pure jitted step, ``lax.scan`` chunks, orbax checkpoint after each chunk)
-> batched MJX evaluation. The run directory holds ``config.json``, ``metrics.jsonl``, ``results.json``,
``learning_curve.png`` and ``checkpoints/``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
import orbax.checkpoint as ocp
from flax import struct

from .config import Config, parse_args, validate
from .costs import engineered_costs, engineered_spec, spearman
from .data import resolve_dataset, sample_batch, sampler_data
from .data.sampler import Batch, SamplerData
from .envs import REFERENCE_SOURCE, normalized_score
from .evaluate import PolicyParams, evaluate
from .learned_costs import LearnedCostConfig, train_learned_costs
from .model import DecisionTransformer
from .parallel import make_mesh, replicate, shard_batch
from .rundir import check_run_dir, exit_code, progress, truncate_metrics
from .subdominance import min_subdominance, returns_to_go, surrogate_rewards

# Fields that may differ between a run and its resumption.
RESUMABLE_CHANGES = ("steps", "eval_episodes", "out", "preset", "devices")


@struct.dataclass
class TrainState:
    step: jax.Array
    params: Any
    opt_state: Any
    rng: jax.Array


def make_model(cfg: Config, act_dim: int, max_timestep: int) -> DecisionTransformer:
    return DecisionTransformer(act_dim=act_dim, embed_dim=cfg.embed_dim, n_layers=cfg.n_layers,
                               n_heads=cfg.n_heads, dropout=cfg.dropout, max_timestep=max_timestep)


def make_optimizer(cfg: Config) -> optax.GradientTransformation:
    """AdamW with the DT paper's linear warm-up to a constant rate, after global-norm clipping."""
    schedule = lambda step: cfg.learning_rate * jnp.minimum((step + 1) / cfg.warmup_steps, 1.0)  # noqa: E731
    return optax.flatten(optax.chain(optax.clip_by_global_norm(cfg.grad_clip),
                                     optax.adamw(schedule, weight_decay=cfg.weight_decay)))


def init_state(model: DecisionTransformer, tx, cfg: Config, obs_dim: int) -> TrainState:
    rng, init_rng = jax.random.split(jax.random.PRNGKey(cfg.seed))
    K = cfg.context_len
    params = model.init(init_rng, jnp.zeros((1, K, obs_dim)), jnp.zeros((1, K, model.act_dim)), jnp.zeros((1, K)),
                        jnp.zeros((1, K), jnp.int32), jnp.ones((1, K), bool))
    return TrainState(step=jnp.zeros((), jnp.int32), params=params, opt_state=tx.init(params), rng=rng)


def action_loss(model: DecisionTransformer, params, batch: Batch, rng) -> jax.Array:
    """Mean squared action error over real (unpadded) tokens, dropout on."""
    pred = model.apply(params, batch.states, batch.actions, batch.returns_to_go, batch.timesteps, batch.mask,
                       deterministic=False, rngs={"dropout": rng})
    err = jnp.mean((pred - batch.actions) ** 2, axis=-1)
    return jnp.sum(err * batch.mask) / jnp.maximum(jnp.sum(batch.mask), 1)


def make_train_step(model: DecisionTransformer, tx, cfg: Config, mesh=None):
    """Pure ``step(state, data) -> (state, loss)``: sample a batch, forward, backward, clipped AdamW update.

    With a ``mesh`` (:func:`minsubdt_jax.parallel.make_mesh`) the batch is split over its devices (data
    parallel); the step computes the same thing on any number of devices."""

    def step(state: TrainState, data: SamplerData):
        rng, k_batch, k_drop = jax.random.split(state.rng, 3)
        batch = shard_batch(sample_batch(k_batch, data, cfg.batch_size, cfg.context_len), mesh)
        loss, grads = jax.value_and_grad(lambda p: action_loss(model, p, batch, k_drop))(state.params)
        updates, opt_state = tx.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        return TrainState(step=state.step + 1, params=params, opt_state=opt_state, rng=rng), loss

    return step


def make_train_chunk(model: DecisionTransformer, tx, cfg: Config, n_steps: int, mesh=None):
    """Jitted ``chunk(state, data) -> (state, losses [n_steps])``: ``n_steps`` train steps in one ``lax.scan``
    (data parallel over ``mesh`` when given: pass ``state`` and ``data`` replicated on it)."""
    step = make_train_step(model, tx, cfg, mesh)

    def chunk(state, data):
        return jax.lax.scan(lambda s, _: step(s, data), state, None, length=n_steps)

    return jax.jit(chunk, donate_argnums=0)


def prepare(cfg: Config, verbose: bool = True) -> dict:
    """Dataset -> cost features -> min-subdominance -> (surrogate) returns-to-go -> sampler arrays."""
    dataset, path = resolve_dataset(cfg.env, cfg.dataset, transitions=cfg.dataset_transitions,
                                    horizon=cfg.episode_length, seed=cfg.dataset_seed, verbose=verbose)
    if dataset.max_len > cfg.episode_length:
        raise ValueError(f"the dataset has episodes of {dataset.max_len} steps, longer than --episode-length "
                         f"{cfg.episode_length}")
    costs = np.asarray(engineered_costs(cfg.env, dataset.observations, dataset.lengths, cfg.episode_length))
    mean, std = dataset.state_stats()
    learned = None
    if cfg.returns == "learned":
        lc_cfg = LearnedCostConfig(cost_dim=cfg.cost_dim, steps=cfg.cost_steps, pairs_per_step=cfg.cost_pairs,
                                   label_noise=cfg.cost_label_noise, seed=cfg.seed)
        learned = train_learned_costs(dataset.observations, dataset.lengths, dataset.returns, lc_cfg, beta=cfg.beta,
                                      horizon=cfg.episode_length, state_mean=mean, state_std=std)
        features = learned.features(dataset.observations, dataset.lengths)
    else:
        features = costs
    ms = min_subdominance(features, features, cfg.beta, alpha_max=cfg.alpha_max, leave_one_out=True)
    ms_value = np.asarray(ms.value)
    rho = spearman(-ms_value, dataset.returns)
    if cfg.returns in ("subdom", "learned"):
        rewards = surrogate_rewards(ms_value, dataset.lengths, dataset.max_len)
        rtg_scale = cfg.rtg_scale or 1.0
        target = 0.0 if cfg.target_return is None else cfg.target_return
    elif cfg.returns == "true":
        rewards = dataset.rewards
        rtg_scale = cfg.rtg_scale or 1000.0
        target = float(dataset.returns.max()) if cfg.target_return is None else cfg.target_return
    else:  # "none": behaviour cloning, every return token 0
        rewards = np.zeros_like(dataset.rewards)
        rtg_scale, target = 1.0, 0.0
    rtg = np.asarray(returns_to_go(rewards, dataset.lengths)) / rtg_scale
    summary = {
        "path": path, "episodes": dataset.num_trajectories, "transitions": dataset.num_transitions,
        "return_mean": float(dataset.returns.mean()), "return_std": float(dataset.returns.std()),
        "normalized_score_mean": float(normalized_score(cfg.env, dataset.returns).mean()),
        "costs_mean": dict(zip(engineered_spec(cfg.env).names, map(float, costs.mean(0)))),
        "min_subdominance_mean": float(ms_value.mean()), "min_subdominance_std": float(ms_value.std()),
        "spearman_neg_min_subdominance_vs_return": rho,
        "min_subdominance_features": "learned" if learned else "engineered",
        # up to 300 demos' engineered cost features, for the demos-vs-rollouts scatter of experiments/table1.py
        "costs_sample": costs[np.sort(np.random.default_rng(0).permutation(len(costs))[:300])].tolist(),
    }
    if learned:
        summary["learned_costs"] = learned.report
    if verbose:
        print(f"dataset {path}: {summary['episodes']} episodes, {summary['transitions']} transitions, return "
              f"{summary['return_mean']:.1f} ± {summary['return_std']:.1f}")
        print(f"min-subdominance {summary['min_subdominance_mean']:.3f} ± {summary['min_subdominance_std']:.3f}; "
              f"Spearman(-min-subdominance, true return) = {rho:.3f}", flush=True)
    if verbose and learned:
        r = learned.report
        print(f"learned costs (K'={cfg.cost_dim}): held-out pair accuracy {r['heldout_pair_accuracy']:.3f}, "
              f"train {r['train_pair_accuracy']:.3f}", flush=True)
    return dict(dataset=dataset, costs=costs, features=features, learned=learned,
                data=sampler_data(dataset, rtg, mean, std), state_mean=mean, state_std=std, rtg_scale=rtg_scale,
                target_return=target, summary=summary)


def train(cfg: Config, resume: bool = False, verbose: bool = True) -> dict:
    """Run one training job end to end in ``cfg.run_dir()``; returns the contents of ``results.json``."""
    cfg = validate(cfg)
    out = cfg.run_dir()
    ckpt_dir = os.path.abspath(os.path.join(out, "checkpoints"))
    check_run_dir(dataclasses.asdict(cfg), out, ckpt_dir, resume, RESUMABLE_CHANGES)
    mesh = make_mesh(cfg.devices, cfg.batch_size)  # checked before anything is written
    prep = prepare(cfg, verbose)  # before anything is written: bad data changes nothing
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, "config.json"), "w") as f:
        f.write(cfg.to_json())
    dataset = prep["dataset"]
    model = make_model(cfg, dataset.act_dim, max(cfg.episode_length, dataset.max_len))
    tx = make_optimizer(cfg)
    state = init_state(model, tx, cfg, dataset.obs_dim)
    mngr = ocp.CheckpointManager(ckpt_dir, options=ocp.CheckpointManagerOptions(max_to_keep=2, create=True))
    if resume and mngr.latest_step() is not None:
        state = mngr.restore(mngr.latest_step(), args=ocp.args.StandardRestore(state))
        if verbose:
            print(f"resumed from step {int(state.step)}", flush=True)
    start = int(state.step)
    state, data = replicate((state, prep["data"]), mesh)
    if verbose and mesh.size > 1:
        print(f"data parallel over {mesh.size} devices: {cfg.batch_size // mesh.size} sequences each", flush=True)
    metrics_path = os.path.join(out, "metrics.jsonl")
    truncate_metrics(metrics_path, start)

    chunks = {}
    t0 = time.time()
    bar = progress(total=cfg.steps, initial=start, disable=not verbose)
    while int(state.step) < cfg.steps:
        n = min(cfg.chunk_steps, cfg.steps - int(state.step))
        if n not in chunks:
            chunks[n] = make_train_chunk(model, tx, cfg, n, mesh)
        tc = time.time()
        state, losses = chunks[n](state, data)
        loss = float(jnp.mean(losses))
        step = int(state.step)
        with open(metrics_path, "a") as f:
            f.write(json.dumps({"step": step, "loss": loss, "chunk_seconds": time.time() - tc}) + "\n")
        mngr.save(step, args=ocp.args.StandardSave(state))
        bar.set_postfix(loss=f"{loss:.4f}")
        bar.update(n)
    bar.close()
    mngr.wait_until_finished()
    train_seconds = time.time() - t0

    results = {"config": dataclasses.asdict(cfg), "dataset": prep["summary"], "references": REFERENCE_SOURCE,
               "train": {"steps": int(state.step), "steps_this_run": int(state.step) - start,
                         "seconds_this_run": train_seconds}}
    if cfg.eval_episodes:
        te = time.time()
        params = PolicyParams(model=state.params, state_mean=prep["state_mean"], state_std=prep["state_std"],
                              target_return=jnp.float32(prep["target_return"]), rtg_scale=jnp.float32(prep["rtg_scale"]),
                              subtract_rewards=jnp.float32(cfg.returns == "true"))
        ev = evaluate(cfg.env, model, params, cfg.context_len, prep["costs"], num_episodes=cfg.eval_episodes,
                      horizon=cfg.episode_length, beta=cfg.beta, seed=cfg.seed + 10_000, learned=prep["learned"],
                      demo_features=prep["features"])
        results["eval"] = ev.summary(engineered_spec(cfg.env).names)
        results["eval"]["target_return"] = prep["target_return"]
        results["eval"]["seconds"] = time.time() - te
        if verbose:
            e = results["eval"]
            print(f"eval: return {e['return_mean']:.1f} ± {e['return_std']:.1f}, normalised "
                  f"{e['normalized_score_mean']:.1f} ({REFERENCE_SOURCE}), min-subdominance "
                  f"{e['min_subdominance_mean']:.3f} (dataset {prep['summary']['min_subdominance_mean']:.3f})")
    with open(os.path.join(out, "results.json"), "w") as f:
        json.dump(results, f, indent=2)
    plot_learning_curve(metrics_path, os.path.join(out, "learning_curve.png"))
    if verbose:
        print(f"wrote {out}/results.json", flush=True)
    return results


def plot_learning_curve(metrics_path: str, png_path: str) -> None:
    """Training loss against step from ``metrics.jsonl``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with open(metrics_path) as f:
        rows = [json.loads(ln) for ln in f if ln.strip()]
    fig, ax = plt.subplots(figsize=(5, 3.2), dpi=100)
    ax.plot([r["step"] for r in rows], [r["loss"] for r in rows], marker=".")
    ax.set(xlabel="gradient step", ylabel="action MSE (train)", yscale="log", title="learning curve")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(png_path)
    plt.close(fig)


def main(argv=None) -> int:
    return exit_code(lambda: train(*parse_args(argv)))


if __name__ == "__main__":
    sys.exit(main())
