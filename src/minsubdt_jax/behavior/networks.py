"""SAC networks: a tanh-squashed Gaussian actor and a pair of Q-functions (the shared ensemble,
:mod:`minsubdt_jax.networks`).

The actor is also the behaviour policy that records datasets: ``policy_step`` is the rollout-policy
signature of :func:`minsubdt_jax.envs.make_rollout` and samples from the stochastic policy, as D4RL did.
"""

from __future__ import annotations

from typing import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

from ..networks import MLP, Critics, tanh_gaussian_sample

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


def DoubleCritic(hidden: Sequence[int] = (256, 256)) -> Critics:
    """``(obs [B, obs], action [B, act]) -> q [2, B]``: two independent Q-networks evaluated as one batch (the shared
    :class:`~minsubdt_jax.networks.Critics`, under the parameter name SAC's critics always had)."""
    return Critics(tuple(hidden), num=2, member_name="VmapQNetwork_0")


def sample_tanh_gaussian(mean, log_std, rng):
    """A reparameterised sample ``a = tanh(u)``, ``u ~ N(mean, exp(log_std))``, and its log-density ``[...]``
    (:func:`~minsubdt_jax.networks.tanh_gaussian_sample`, the critic agents' too)."""
    return tanh_gaussian_sample(rng, mean, log_std)


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


def amateur_policy_step(params, carry, obs, prev_reward, t, rng):
    """PEDA's "amateur" behaviour (D4MORL, Zhu et al. 2023): the stochastic actor's action, scaled with probability
    0.65 by a factor drawn from U(0.35, 1.65) (one factor per step; the rollout clips to [-1, 1])."""
    k_act, k_coin, k_scale = jax.random.split(rng, 3)
    carry, action = policy_step(params, carry, obs, prev_reward, t, k_act)
    scale = jnp.where(jax.random.uniform(k_coin) < 0.65, jax.random.uniform(k_scale, minval=0.35, maxval=1.65), 1.0)
    return carry, action * scale


def deterministic_policy_step(params, carry, obs, prev_reward, t, rng):
    """The actor's mode ``tanh(mean)`` in the :func:`~minsubdt_jax.envs.make_rollout` signature."""
    mean, _ = actor_from_params(params).apply(params, obs)
    return carry, jnp.tanh(mean)
