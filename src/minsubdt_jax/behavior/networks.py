"""SAC networks: a tanh-squashed Gaussian actor and a pair of Q-functions (batched with ``nn.vmap``).

The actor is also the behaviour policy that records datasets: ``policy_step`` is the rollout-policy
signature of :func:`minsubdt_jax.envs.make_rollout` and samples from the stochastic policy, as D4RL did.
"""

from __future__ import annotations

from typing import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

from ..networks import MLP

LOG_STD_MIN, LOG_STD_MAX = -5.0, 2.0


class Actor(nn.Module):
    """``obs [..., obs] -> (mean [..., act], log_std [..., act])`` of the pre-tanh Gaussian."""

    act_dim: int
    hidden: Sequence[int] = (256, 256)

    @nn.compact
    def __call__(self, obs):
        x = MLP(self.hidden, name="torso")(obs)
        mean = nn.Dense(self.act_dim, name="mean")(x)
        log_std = jnp.clip(nn.Dense(self.act_dim, name="log_std")(x), LOG_STD_MIN, LOG_STD_MAX)
        return mean, log_std


class QNetwork(nn.Module):
    hidden: Sequence[int] = (256, 256)

    @nn.compact
    def __call__(self, obs, action):
        x = MLP(self.hidden)(jnp.concatenate([obs, action], -1))
        return nn.Dense(1)(x)[..., 0]


class DoubleCritic(nn.Module):
    """``(obs [B, obs], action [B, act]) -> q [2, B]``: two independent Q-networks evaluated as one batch."""

    hidden: Sequence[int] = (256, 256)

    @nn.compact
    def __call__(self, obs, action):
        vq = nn.vmap(QNetwork, variable_axes={"params": 0}, split_rngs={"params": True}, in_axes=None,
                     out_axes=0, axis_size=2)
        return vq(self.hidden)(obs, action)


def sample_tanh_gaussian(mean, log_std, rng):
    """A reparameterised sample ``a = tanh(u)``, ``u ~ N(mean, exp(log_std))``, and its log-density ``[...]``
    (with the tanh change of variables, ``log(1 - tanh(u)^2) = 2 (log 2 - u - softplus(-2u))``)."""
    std = jnp.exp(log_std)
    u = mean + std * jax.random.normal(rng, mean.shape)
    logp_u = -0.5 * (((u - mean) / std) ** 2 + 2 * log_std + jnp.log(2 * jnp.pi))
    log_det = 2.0 * (jnp.log(2.0) - u - jax.nn.softplus(-2.0 * u))
    return jnp.tanh(u), jnp.sum(logp_u - log_det, axis=-1)


def actor_from_params(params) -> Actor:
    """The :class:`Actor` whose layer sizes match ``params`` (so snapshots need no separate metadata)."""
    p = params["params"]
    hidden = tuple(p["torso"][f"Dense_{i}"]["kernel"].shape[1] for i in range(len(p["torso"])))
    return Actor(act_dim=p["mean"]["kernel"].shape[1], hidden=hidden)


def policy_step(params, carry, obs, prev_reward, t, rng):
    """Stochastic behaviour policy in the :func:`~minsubdt_jax.envs.make_rollout` signature."""
    mean, log_std = actor_from_params(params).apply(params, obs)
    action, _ = sample_tanh_gaussian(mean, log_std, rng)
    return carry, action


def deterministic_policy_step(params, carry, obs, prev_reward, t, rng):
    """The actor's mode ``tanh(mean)`` in the :func:`~minsubdt_jax.envs.make_rollout` signature."""
    mean, _ = actor_from_params(params).apply(params, obs)
    return carry, jnp.tanh(mean)
