"""Train a Minimally Subdominant Decision Transformer (or a DT, or BC) and evaluate it in MJX.

    python -m minsubdt_jax.train --env walker                       # cpu preset, surrogate returns
    python -m minsubdt_jax.train --env walker --returns learned     # costs learned from preferences (eq. 3)
    python -m minsubdt_jax.train --env hopper --returns true        # plain DT on the true rewards
    python -m minsubdt_jax.train --env hopper --returns none        # BC: the same transformer, return tokens 0
    python -m minsubdt_jax.train --env hopper --preset smoke --out /tmp/run
    python -m minsubdt_jax.train --env hopper --out /tmp/run --resume   # continue after an interruption
    python -m minsubdt_jax.train --env hopper --seeds 3             # seeds 0, 1, 2 as one vmapped program

Several processes (one machine or many; each runs the same command with its own --process-id):

    python -m minsubdt_jax.train --env hopper --num-processes 2 --process-id 0 --coordinator-address localhost:8476 &
    python -m minsubdt_jax.train --env hopper --num-processes 2 --process-id 1 --coordinator-address localhost:8476

Pipeline: dataset -> engineered (or learned) cost features -> min-subdominance (eq. 2, leave-one-out) -> surrogate
returns-to-go -> DT training (pure jitted step, ``lax.scan`` chunks, orbax checkpoint after each chunk)
-> batched MJX evaluation. ``--seeds S`` trains S independent models with ``vmap`` over a leading seed axis of
the train state, inside the same jitted step, and evaluates them in one rollout program. The batch is split
over every device of every process (:mod:`minsubdt_jax.parallel`). The run directory holds ``config.json``, ``metrics.jsonl``, ``results.json``,
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

from .caches import enable_compilation_cache
from .config import Config, parse_args, validate
from .costs import engineered_costs, engineered_spec, spearman
from .data import resolve_dataset, sample_batch, sampler_data
from .data.sampler import Batch, SamplerData
from .envs import REFERENCE_SOURCE, normalized_score
from .evaluate import PolicyParams, evaluate_seeds
from .learned_costs import LearnedCostConfig, train_learned_costs
from .model import DecisionTransformer
from .parallel import (assert_same_across_processes, gather, init_distributed, is_main_process, make_mesh, replicate,
                       shard_batch)
from .rundir import (DATASET_FILE, check_run_dir, check_same_data, exit_code, progress, truncate_metrics,
                     write_atomic)
from .subdominance import min_subdominance, returns_to_go, surrogate_rewards

# Fields that may differ between a run and its resumption.
RESUMABLE_CHANGES = ("steps", "eval_episodes", "out", "preset", "devices", "coordinator_address", "num_processes",
                     "process_id")


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


def init_state(model: DecisionTransformer, tx, cfg: Config, obs_dim: int, key: jax.Array | None = None) -> TrainState:
    """Fresh parameters, optimiser state and step rng from ``key`` (default ``PRNGKey(cfg.seed)``)."""
    rng, init_rng = jax.random.split(jax.random.PRNGKey(cfg.seed) if key is None else key)
    K = cfg.context_len
    params = model.init(init_rng, jnp.zeros((1, K, obs_dim)), jnp.zeros((1, K, model.act_dim)), jnp.zeros((1, K)),
                        jnp.zeros((1, K), jnp.int32), jnp.ones((1, K), bool))
    return TrainState(step=jnp.zeros((), jnp.int32), params=params, opt_state=tx.init(params), rng=rng)


def init_seed_states(model: DecisionTransformer, tx, cfg: Config, obs_dim: int, seeds) -> TrainState:
    """One :func:`init_state` per seed, stacked on a leading seed axis ``[S, ...]`` (``vmap`` over the keys, so
    seed s starts exactly where a single-seed run with ``--seed s`` does)."""
    keys = jnp.stack([jax.random.PRNGKey(s) for s in seeds])
    return jax.jit(jax.vmap(lambda k: init_state(model, tx, cfg, obs_dim, k)))(keys)


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


def make_train_chunk(model: DecisionTransformer, tx, cfg: Config, n_steps: int, mesh=None, *, seed_axis: bool = False,
                     data_axis: int | None = None):
    """Jitted ``chunk(state, data) -> (state, losses [n_steps])``: ``n_steps`` train steps in one ``lax.scan``
    (data parallel over ``mesh`` when given: pass ``state`` and ``data`` replicated on it).

    With ``seed_axis`` the state has a leading seed axis (:func:`init_seed_states`) and every step is
    ``vmap``-ed over it: S independent models train in one program, ``losses [n_steps, S]``. ``data_axis``
    0 gives each seed its own sampler data (stacked ``[S, ...]``), ``None`` shares one."""
    step = make_train_step(model, tx, cfg, mesh)
    if seed_axis:
        step = jax.vmap(step, in_axes=(0, data_axis))

    def chunk(state, data):
        return jax.lax.scan(lambda s, _: step(s, data), state, None, length=n_steps)

    return jax.jit(chunk, donate_argnums=0)


def prepare(cfg: Config, verbose: bool = True) -> dict:
    """Dataset -> cost features -> min-subdominance -> (surrogate) returns-to-go -> sampler arrays."""
    source = resolve_dataset(cfg.env, cfg.dataset, transitions=cfg.dataset_transitions, horizon=cfg.episode_length,
                             seed=cfg.dataset_seed, verbose=verbose)
    dataset, path = source.data, source.path
    if dataset.max_len > cfg.episode_length:
        raise ValueError(f"the dataset has episodes of {dataset.max_len} steps, longer than --episode-length "
                         f"{cfg.episode_length}")
    if dataset.num_trajectories < 2:
        raise ValueError(f"{path}: the dataset has {dataset.num_trajectories} episode; min-subdominance scores each "
                         f"demonstration against the others and needs at least 2")
    costs = np.asarray(engineered_costs(cfg.env, dataset.observations, dataset.lengths, cfg.episode_length))
    with np.errstate(over="ignore", invalid="ignore"):
        mean, std = dataset.state_stats()
    if not (np.isfinite(mean).all() and np.isfinite(std).all()):
        raise ValueError(f"{path}: the observations' mean or standard deviation overflows float32; the states "
                         f"cannot be normalised")
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
    if not np.isfinite(rtg).all():
        raise ValueError(f"{path}: the returns-to-go overflow float32 (divided by --rtg-scale {rtg_scale})")
    summary = {
        "path": path, "sha256": source.sha256, "timeouts_inferred": source.timeouts_inferred,
        "episodes": dataset.num_trajectories, "transitions": dataset.num_transitions,
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
    """Run one training job end to end in ``cfg.run_dir()``; returns the contents of ``results.json``.

    ``cfg.seeds`` models (seeds ``cfg.seed ...``) train together; in a multi-process job (``cfg.num_processes``)
    every process calls this, and only process 0 writes the run directory (checkpoints are written jointly
    by orbax)."""
    cfg = validate(cfg)
    init_distributed(cfg.coordinator_address, cfg.num_processes, cfg.process_id)
    main = is_main_process()
    verbose = verbose and main
    out = cfg.run_dir()
    ckpt_dir = os.path.abspath(os.path.join(out, "checkpoints"))
    check_run_dir(dataclasses.asdict(cfg), out, ckpt_dir, resume, RESUMABLE_CHANGES)
    mesh = make_mesh(cfg.devices, cfg.batch_size)  # checked before anything is written
    seeds = list(range(cfg.seed, cfg.seed + cfg.seeds))
    # before anything is written: bad data changes nothing. Only learned costs depend on the seed.
    seed_cfgs = [dataclasses.replace(cfg, seed=s) for s in seeds] if cfg.returns == "learned" else [cfg]
    preps = [prepare(c, verbose) for c in seed_cfgs]
    datas = [p["data"] for p in preps]
    data = datas[0] if len(datas) == 1 else jax.tree.map(lambda *x: jnp.stack(x), *datas)
    assert_same_across_processes([np.asarray(x) for x in jax.tree.leaves(data)],
                                 "the training data (every process must load the same dataset)")
    check_same_data(out, preps[0]["summary"]["sha256"], resume)
    if main:
        os.makedirs(out, exist_ok=True)
        write_atomic(os.path.join(out, "config.json"), cfg.to_json())
        write_atomic(os.path.join(out, DATASET_FILE), json.dumps(
            {k: preps[0]["summary"][k] for k in ("path", "sha256", "episodes", "transitions")}, indent=2))
    dataset = preps[0]["dataset"]
    model = make_model(cfg, dataset.act_dim, max(cfg.episode_length, dataset.max_len))
    tx = make_optimizer(cfg)
    state = init_seed_states(model, tx, cfg, dataset.obs_dim, seeds)
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

    chunks = {}
    t0 = time.time()
    step = start
    bar = progress(total=cfg.steps, initial=start, disable=not verbose)
    while step < cfg.steps:
        n = min(cfg.chunk_steps, cfg.steps - step)
        if n not in chunks:
            chunks[n] = make_train_chunk(model, tx, cfg, n, mesh, seed_axis=True,
                                         data_axis=None if len(datas) == 1 else 0)
        tc = time.time()
        state, losses = chunks[n](state, data)
        per_seed = np.asarray(gather(losses)).mean(0)  # [S]
        if not np.isfinite(per_seed).all():
            last = f"the last checkpoint is step {step}" if step else "no checkpoint was written"
            raise ValueError(f"training diverged: non-finite loss {per_seed.tolist()} in steps {step + 1}-{step + n} "
                             f"(not checkpointed; {last}); try a lower --learning-rate")
        step += n
        if main:
            with open(metrics_path, "a") as f:
                f.write(json.dumps({"step": step, "loss": float(per_seed.mean()), "loss_per_seed": per_seed.tolist(),
                                    "chunk_seconds": time.time() - tc}) + "\n")
        mngr.save(step, args=ocp.args.StandardSave(state))
        bar.set_postfix(loss=f"{per_seed.mean():.4f}")
        bar.update(n)
    bar.close()
    mngr.wait_until_finished()
    train_seconds = time.time() - t0

    results = {"config": dataclasses.asdict(cfg), "dataset": preps[0]["summary"], "references": REFERENCE_SOURCE,
               "seeds": seeds,
               "train": {"steps": step, "steps_this_run": step - start, "seconds_this_run": train_seconds}}
    if len(preps) > 1:
        results["dataset"]["learned_costs_per_seed"] = [p["summary"]["learned_costs"] for p in preps]
    if cfg.eval_episodes:
        te = time.time()
        per_seed = evaluate_run(cfg, model, state.params, preps, seeds, mesh)
        results["eval_per_seed"] = per_seed
        results["eval"] = per_seed[0] if len(seeds) == 1 else across_seeds(per_seed)
        results["eval"]["seconds"] = time.time() - te
        if verbose:
            e = results["eval"]
            over = "episodes" if len(seeds) == 1 else f"{len(seeds)} seeds"
            print(f"eval: return {e['return_mean']:.1f} ± {e['return_std']:.1f}, normalised "
                  f"{e['normalized_score_mean']:.1f} ± {e['normalized_score_std']:.1f} over {over} "
                  f"({REFERENCE_SOURCE}), min-subdominance {e['min_subdominance_mean']:.3f} "
                  f"(dataset {preps[0]['summary']['min_subdominance_mean']:.3f})")
    if main:
        write_atomic(os.path.join(out, "results.json"), json.dumps(results, indent=2))
        plot_learning_curve(metrics_path, os.path.join(out, "learning_curve.png"))
    if verbose:
        print(f"wrote {out}/results.json", flush=True)
    return results


def evaluate_run(cfg: Config, model: DecisionTransformer, params, preps: list[dict], seeds: list[int], mesh) -> list:
    """Evaluate the S trained models (``params [S, ...]``) in one batched MJX program, episodes split over
    ``mesh``; seed s is evaluated with rng seed ``s + 10000``. Returns one summary dict per seed."""
    per = [preps[min(i, len(preps) - 1)] for i in range(len(seeds))]  # one prep per seed (shared unless learned)
    stack = lambda key, dtype=np.float32: np.stack([np.asarray(p[key], dtype) for p in per])  # noqa: E731
    policy = PolicyParams(model=params, state_mean=stack("state_mean"), state_std=stack("state_std"),
                          target_return=stack("target_return"), rtg_scale=stack("rtg_scale"),
                          subtract_rewards=np.full(len(seeds), cfg.returns == "true", np.float32))
    learned = [p["learned"] for p in per] if cfg.returns == "learned" else None
    evs = evaluate_seeds(cfg.env, model, replicate(policy, mesh), cfg.context_len, per[0]["costs"],
                         num_episodes=cfg.eval_episodes, horizon=cfg.episode_length, beta=cfg.beta,
                         seeds=[s + 10_000 for s in seeds], learned=learned,
                         demo_features=[p["features"] for p in per] if learned else None, mesh=mesh)
    names = engineered_spec(cfg.env).names
    return [dict(ev.summary(names), seed=s, target_return=p["target_return"]) for ev, s, p in zip(evs, seeds, per)]


def across_seeds(per_seed: list[dict]) -> dict:
    """The seed-level summary of a multi-seed run: mean ± std over seeds (n = S) of each seed's mean, and
    every seed's episodes pooled for ``returns`` and ``costs``."""
    out = {"seeds": [e["seed"] for e in per_seed], "episodes": sum(e["episodes"] for e in per_seed)}
    for base in ("return", "normalized_score", "min_subdominance", "learned_min_subdominance"):
        if base + "_mean" in per_seed[0]:
            v = np.array([e[base + "_mean"] for e in per_seed])
            out.update({base + "_mean": float(v.mean()), base + "_std": float(v.std()), base + "_per_seed": v.tolist()})
    for key in ("length_mean", "better_than_mean_demo_share"):
        out[key] = float(np.mean([e[key] for e in per_seed]))
    out["costs_mean"] = {k: float(np.mean([e["costs_mean"][k] for e in per_seed])) for k in per_seed[0]["costs_mean"]}
    out["returns"] = [r for e in per_seed for r in e["returns"]]
    out["costs"] = [c for e in per_seed for c in e["costs"]]
    out["target_return"] = per_seed[0]["target_return"]
    return out


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
    enable_compilation_cache()
    return exit_code(lambda: train(*parse_args(argv)))


if __name__ == "__main__":
    sys.exit(main())
