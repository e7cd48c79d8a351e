"""A trained MinSubDT checkpoint evaluated at targets from the data's range (is a low score the target's doing?).

    python experiments/probe_targets.py runs/curves/walker-medium-cpu-k20-cosine-ema0.999 --step 16000

Restores the run's checkpoint at ``--step`` (its EMA parameters when it keeps them), takes its MinSubDT models
(the first ``--seeds`` models of the run: MinSubDT comes first in ``--method minsubdt,...``), and evaluates each on
``--episodes`` episodes conditioned on a surrogate return of 0 (the default), the best demo's, and the 5 %, 25 % and
50 % quantiles of the demos' -min-subdominance. Prints one line per target.

    python experiments/probe_targets.py RUN --step N --offline

``--offline`` evaluates no episode: every model of the run (each method and seed) predicts the data's actions on
``--windows`` windows of its own training data (dropout off): its action error with its own return tokens, and,
for MinSubDT, with every return token set to the evaluation target 0, and how far that moves its actions. A model
that fits the data like the others but fails in its rollouts fails in closed loop, not in fitting.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys

import jax
import numpy as np


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run")
    p.add_argument("--step", type=int, default=None, help="default: the last checkpoint")
    p.add_argument("--episodes", type=int, default=30)
    p.add_argument("--offline", action="store_true", help="action errors on the data's windows, no episodes")
    p.add_argument("--windows", type=int, default=4096)
    a = p.parse_args(argv)
    if not os.path.exists(os.path.join(a.run, "config.json")):
        p.error(f"{a.run}: not a run directory (no config.json)")
    import orbax.checkpoint as ocp

    from minsubdt_jax.agents import make_agent
    from minsubdt_jax.agents.base import eval_params, init_seed_states, make_optimizer
    from minsubdt_jax.config import Config
    from minsubdt_jax.data.d4rl import file_dynamics
    from minsubdt_jax.methods import get_method
    from minsubdt_jax.parallel import make_mesh
    from minsubdt_jax.pipeline import load, prepare
    from minsubdt_jax.program import evaluate_models

    with open(os.path.join(a.run, "config.json")) as f:
        cfg = Config(**json.load(f))
    if cfg.methods[0] != "minsubdt":
        raise SystemExit(f"{a.run} trains {cfg.method}: the first method must be minsubdt")
    src = load(cfg, False)
    dynamics, _ = file_dynamics(src, cfg.env, cfg.dynamics)
    m = get_method("minsubdt")
    prep = prepare(cfg, m, False, src, dynamics)
    agent = make_agent("dt", cfg, src.data.obs_dim, src.data.act_dim, max(cfg.episode_length, src.data.max_len))
    seeds = list(range(cfg.seed, cfg.seed + cfg.seeds))
    state = init_seed_states(agent, make_optimizer(cfg), seeds * len(cfg.methods), ema=cfg.ema_decay > 0)
    mngr = ocp.CheckpointManager(os.path.abspath(os.path.join(a.run, "checkpoints")))
    step = a.step if a.step is not None else mngr.latest_step()
    state = mngr.restore(step, args=ocp.args.StandardRestore(state))
    if a.offline:
        return offline(a, cfg, agent, eval_params(state), seeds, src, dynamics, step)
    params = jax.tree.map(lambda x: x[:len(seeds)], eval_params(state))
    ms = prep.min_subdominance
    targets = {"0 (the default)": 0.0, "the best demo": float(-ms.min()), "5 % quantile": float(-np.quantile(ms, .05)),
               "25 % quantile": float(-np.quantile(ms, .25)), "median": float(-np.median(ms))}
    print(f"{a.run} at step {step}: MinSubDT seeds {seeds}, {a.episodes} episodes each, normalised score")
    mesh = make_mesh(0, cfg.batch_size)
    for name, target in targets.items():
        p1 = dataclasses.replace(prep, target_return=target)
        ev = evaluate_models(cfg, agent, params, [(m, s) for s in seeds], [p1] * len(seeds), mesh, a.episodes,
                             cfg.physics, dynamics)
        print(f"  target {target:7.3f} ({name}): " + ", ".join(f"seed {s} {e['normalized_score_mean']:.1f}"
                                                               for s, e in zip(seeds, ev)), flush=True)
    return 0


def offline(a, cfg, agent, params, seeds, src, dynamics, step) -> int:
    import jax.numpy as jnp

    from minsubdt_jax.data import sample_batch
    from minsubdt_jax.methods import get_method
    from minsubdt_jax.pipeline import prepare

    print(f"{a.run} at step {step}: action error (mean squared, real tokens) on {a.windows} windows of the data")
    for i, (name, seed) in enumerate((mth, s) for mth in cfg.methods for s in seeds):
        prep = prepare(cfg, get_method(name), False, src, dynamics)
        batch = sample_batch(jax.random.PRNGKey(123), prep.sampler, a.windows, agent.context_len)
        p_i = jax.tree.map(lambda x: x[i], params)

        def predict(b):
            return agent.model.apply(p_i, b.states, b.actions, b.returns_to_go, b.timesteps, b.mask, deterministic=True)

        def err(pred, b):
            e = jnp.mean((pred - b.actions) ** 2, -1)
            return float(jnp.sum(e * b.mask) / jnp.sum(b.mask))

        own = predict(batch)
        line = f"  {name} seed {seed}: {err(own, batch):.4f}"
        if name == "minsubdt":
            zero = batch.replace(returns_to_go=jnp.where(batch.mask, 0.0, 0.0))
            at0 = predict(zero)
            line += (f"; every return token 0 (the target): {err(at0, batch):.4f}, actions moved by "
                     f"{float(jnp.sqrt(jnp.mean((at0 - own) ** 2))):.4f} rms")
        print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
