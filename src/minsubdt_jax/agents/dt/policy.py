"""The Decision Transformer as a rollout policy: a fixed-length, left-padded context of the last K steps.

It is conditioned on a target return: for surrogate (subdominance) returns a value in ``[-K_costs, 0]`` (0 =
dominate every demo by the margin), which stays constant along the episode because surrogate rewards are 0 before
the last step; for true returns the target falls by each reward received, as in the DT paper. A vector method's
target is one return per cost metric ``[R]``, constant along the episode (its rewards, too, are paid at the end).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from flax import struct

from ..base import PolicyInputs
from .networks import DecisionTransformer


@struct.dataclass
class Context:
    """The last K steps of each episode: states ``[N, K, obs]``, actions ``[N, K, act]``, returns_to_go
    ``[N, K]`` or ``[N, K, R]`` (unscaled), timesteps ``[N, K]``, mask ``[N, K]``."""

    states: jax.Array
    actions: jax.Array
    returns_to_go: jax.Array
    timesteps: jax.Array
    mask: jax.Array


def return_shape(return_dim: int) -> tuple:
    """The trailing shape of a step's return token: ``()`` for one return, ``(R,)`` for one per metric."""
    return (return_dim,) if return_dim else ()


def empty_context(num_episodes: int, context_len: int, obs_dim: int, act_dim: int, return_dim: int = 0) -> Context:
    n, k = num_episodes, context_len
    return Context(jnp.zeros((n, k, obs_dim)), jnp.zeros((n, k, act_dim)),
                   jnp.zeros((n, k) + return_shape(return_dim)), jnp.zeros((n, k), jnp.int32), jnp.zeros((n, k), bool))


@functools.lru_cache(maxsize=None)
def dt_policy(model: DecisionTransformer):
    """The rollout policy of ``model`` (cached per model so the compiled rollout is reused)."""

    def policy(p: PolicyInputs, ctx: Context, obs, prev_reward, t, rng):
        def push(buf, new):
            return jnp.concatenate([buf[:, 1:], new[:, None]], axis=1)

        last_rtg = ctx.returns_to_go[:, -1]  # [n] or, a return per metric, [n, R]
        paid = (p.subtract_rewards * prev_reward).reshape(prev_reward.shape + (1,) * (last_rtg.ndim - 1))
        rtg = jnp.where(t == 0, p.target_return, last_rtg - paid)
        n = obs.shape[0]
        ctx = Context(
            states=push(ctx.states, p.normalise(obs)),
            actions=push(ctx.actions, jnp.zeros((n, ctx.actions.shape[-1]))),
            returns_to_go=push(ctx.returns_to_go, jnp.broadcast_to(rtg, last_rtg.shape)),
            timesteps=push(ctx.timesteps, jnp.full((n,), t, jnp.int32)),
            mask=push(ctx.mask, jnp.ones((n,), bool)),
        )
        pred = model.apply(p.params, ctx.states, ctx.actions, ctx.returns_to_go / p.rtg_scale, ctx.timesteps,
                           ctx.mask, last_only=True)  # only what the next action needs
        return ctx.replace(actions=ctx.actions.at[:, -1].set(pred)), pred

    return policy
