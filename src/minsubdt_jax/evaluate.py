"""Evaluation: a Decision Transformer policy rolled out in batched MJX, scored by return and by costs.

All episodes run in parallel inside the one jitted while-loop of :func:`minsubdt_jax.envs.make_rollout`;
the policy keeps a fixed-length, left-padded context of the last K steps. It is conditioned on a target
return: for surrogate (subdominance) returns a value in ``[-K_costs, 0]`` (0 = dominate every demo by the
margin), which stays constant along the episode because surrogate rewards are 0 before the last step; for
true returns the target is decreased by each reward received, as in the DT paper.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from .costs import engineered_costs
from .envs import make_rollout, normalized_score
from .model import DecisionTransformer
from .parallel import gather
from .subdominance import min_subdominance


@struct.dataclass
class PolicyParams:
    """Traced inputs of the DT policy: model params, state normalisation ``[obs]``, target return (unscaled),
    return scale, and whether rewards are subtracted from the return-to-go (1.0 for true returns)."""

    model: dict
    state_mean: jax.Array
    state_std: jax.Array
    target_return: jax.Array
    rtg_scale: jax.Array
    subtract_rewards: jax.Array


@struct.dataclass
class Context:
    """The last K steps of each episode: states ``[N, K, obs]``, actions ``[N, K, act]``, returns_to_go
    ``[N, K]`` (unscaled), timesteps ``[N, K]``, mask ``[N, K]``."""

    states: jax.Array
    actions: jax.Array
    returns_to_go: jax.Array
    timesteps: jax.Array
    mask: jax.Array


def empty_context(num_episodes: int, context_len: int, obs_dim: int, act_dim: int) -> Context:
    n, k = num_episodes, context_len
    return Context(jnp.zeros((n, k, obs_dim)), jnp.zeros((n, k, act_dim)), jnp.zeros((n, k)),
                   jnp.zeros((n, k), jnp.int32), jnp.zeros((n, k), bool))


@functools.lru_cache(maxsize=None)
def dt_policy(model: DecisionTransformer):
    """The rollout policy of ``model`` (cached per model so the compiled rollout is reused)."""

    def policy(p: PolicyParams, ctx: Context, obs, prev_reward, t, rng):
        def push(buf, new):
            return jnp.concatenate([buf[:, 1:], new[:, None]], axis=1)

        last_rtg = ctx.returns_to_go[:, -1]
        rtg = jnp.where(t == 0, p.target_return, last_rtg - p.subtract_rewards * prev_reward)
        n = obs.shape[0]
        ctx = Context(
            states=push(ctx.states, (obs - p.state_mean) / p.state_std),
            actions=push(ctx.actions, jnp.zeros((n, ctx.actions.shape[-1]))),
            returns_to_go=push(ctx.returns_to_go, jnp.broadcast_to(rtg, (n,))),
            timesteps=push(ctx.timesteps, jnp.full((n,), t, jnp.int32)),
            mask=push(ctx.mask, jnp.ones((n,), bool)),
        )
        pred = model.apply(p.model, ctx.states, ctx.actions, ctx.returns_to_go / p.rtg_scale, ctx.timesteps,
                           ctx.mask)[:, -1]
        return ctx.replace(actions=ctx.actions.at[:, -1].set(pred)), pred

    return policy


@dataclass
class EvalResult:
    """Per-episode results (numpy): returns ``[n]``, lengths ``[n]``, normalized ``[n]``, costs ``[n, K]``
    (engineered cost features), min_subdominance ``[n]`` against the demo set's engineered features,
    beats_mean_demo ``[n]`` (every engineered feature below the demos' mean), and, for a run on learned
    costs, learned_min_subdominance ``[n]`` against the demos' learned features."""

    returns: np.ndarray
    lengths: np.ndarray
    normalized: np.ndarray
    costs: np.ndarray
    min_subdominance: np.ndarray
    beats_mean_demo: np.ndarray
    learned_min_subdominance: np.ndarray | None = None

    def summary(self, cost_names) -> dict:
        out = {
            "episodes": int(len(self.returns)),
            "return_mean": float(self.returns.mean()), "return_std": float(self.returns.std()),
            "normalized_score_mean": float(self.normalized.mean()),
            "normalized_score_std": float(self.normalized.std()),
            "length_mean": float(self.lengths.mean()),
            "costs_mean": {n: float(v) for n, v in zip(cost_names, self.costs.mean(0))},
            "min_subdominance_mean": float(self.min_subdominance.mean()),
            "min_subdominance_std": float(self.min_subdominance.std()),
            "better_than_mean_demo_share": float(self.beats_mean_demo.mean()),
            "returns": self.returns.tolist(), "costs": self.costs.tolist(),
        }
        if self.learned_min_subdominance is not None:
            out["learned_min_subdominance_mean"] = float(self.learned_min_subdominance.mean())
            out["learned_min_subdominance_std"] = float(self.learned_min_subdominance.std())
        return out


def evaluate(env: str, model: DecisionTransformer, params: PolicyParams, context_len: int, demo_costs,
             *, num_episodes: int, horizon: int = 1000, beta=1.0, seed: int = 0, learned=None,
             demo_features=None, mesh=None) -> EvalResult:
    """Roll ``model`` out for ``num_episodes`` parallel episodes of at most ``horizon`` steps and score them.

    ``demo_costs [M, K]`` are the dataset's engineered cost features; each rollout's min-subdominance
    (eq. 2, margin ``beta``) is computed against them, and whether it beats their mean on every feature.
    With ``learned`` (a :class:`minsubdt_jax.learned_costs.LearnedCosts`) and ``demo_features [M, K']`` (the
    demos' learned features), the rollouts' min-subdominance on the learned features is reported too.
    With a ``mesh`` the episodes are split over its devices (see :func:`evaluate_seeds`).
    """
    stacked = jax.tree.map(lambda x: jnp.asarray(x)[None], params)
    return evaluate_seeds(env, model, stacked, context_len, demo_costs, num_episodes=num_episodes, horizon=horizon,
                          beta=beta, seeds=[seed], learned=None if learned is None else [learned],
                          demo_features=None if demo_features is None else [demo_features], mesh=mesh)[0]


def evaluate_seeds(env: str, model: DecisionTransformer, params: PolicyParams, context_len: int, demo_costs,
                   *, num_episodes: int, horizon: int = 1000, beta=1.0, seeds, learned=None, demo_features=None,
                   mesh=None) -> list[EvalResult]:
    """:func:`evaluate` for S models at once: ``params`` has a leading seed axis ``[S, ...]`` and ``seeds [S]``
    are their evaluation seeds; one jitted program rolls out ``S x num_episodes`` episodes (``vmap`` over the
    seed axis). ``learned`` and ``demo_features``, when given, are lists of S (one cost model per seed).

    With a ``mesh`` (:func:`minsubdt_jax.parallel.make_mesh`) each seed's episodes are split over the mesh's
    devices, in every process of a multi-process job; the number of episodes rolled out is rounded up to a
    multiple of the mesh size and the first ``num_episodes`` are scored, so the result does not depend on the
    device count. Returns one :class:`EvalResult` per seed.
    """
    size = 1 if mesh is None else mesh.size
    n_run = -(-num_episodes // size) * size
    obs_dim = params.state_mean.shape[-1]
    run = _seed_rollout(env, model, n_run, horizon, mesh)
    ctx = empty_context(n_run, context_len, obs_dim, model.act_dim)
    keys = jnp.stack([jax.random.PRNGKey(s) for s in seeds])
    ro = gather(run(params, ctx, keys))
    demo_costs = np.asarray(demo_costs)
    results = []
    for i in range(len(seeds)):
        obs, lengths = ro.observations[i, :num_episodes], ro.lengths[i, :num_episodes]
        costs = np.asarray(engineered_costs(env, obs, lengths, horizon))
        returns = np.asarray(ro.rewards[i, :num_episodes]).sum(1)
        ms = min_subdominance(costs, demo_costs, beta)
        learned_ms = None
        if learned is not None:
            feats = learned[i].features(obs, lengths)
            learned_ms = np.asarray(min_subdominance(feats, np.asarray(demo_features[i]), beta).value)
        results.append(EvalResult(
            returns=returns, lengths=np.asarray(lengths), normalized=normalized_score(env, returns), costs=costs,
            min_subdominance=np.asarray(ms.value), beats_mean_demo=np.all(costs < demo_costs.mean(0), axis=1),
            learned_min_subdominance=learned_ms))
    return results


@functools.lru_cache(maxsize=16)
def _seed_rollout(env: str, model: DecisionTransformer, num_episodes: int, horizon: int, mesh):
    """Jitted ``run(params [S, ...], context, rngs [S]) -> Rollout [S, n, ...]`` (cached per shape)."""
    run = make_rollout(env, dt_policy(model), num_episodes, horizon, mesh)
    return jax.jit(jax.vmap(run, in_axes=(0, None, 0)))
