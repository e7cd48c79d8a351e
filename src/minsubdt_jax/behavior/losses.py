"""SAC losses (Haarnoja et al. 2018, with automatic entropy tuning), as pure functions of a batch.

Terminations (``discount = 0``) bootstrap nothing; time-outs are stored as ordinary transitions whose
``next_obs`` is the true next observation, so they bootstrap as if the episode went on.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from .networks import Actor, DoubleCritic, sample_tanh_gaussian


@struct.dataclass
class Transition:
    """A batch of transitions: obs ``[B, obs]``, action ``[B, act]``, reward ``[B]``, discount ``[B]``
    (0 at a termination, else 1), next_obs ``[B, obs]``."""

    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    discount: jax.Array
    next_obs: jax.Array


def critic_loss(critic_params, target_critic_params, actor_params, log_alpha, batch: Transition, rng, *,
                actor: Actor, critic: DoubleCritic, gamma: float):
    """Soft Bellman error ``0.5 sum_i mean (Q_i(s,a) - y)^2``, ``y = r + γ d (min_j Q'_j(s',a') - α log π(a'|s'))``."""
    mean, log_std = actor.apply(actor_params, batch.next_obs)
    next_action, next_logp = sample_tanh_gaussian(mean, log_std, rng)
    next_q = jnp.min(critic.apply(target_critic_params, batch.next_obs, next_action), axis=0)
    target = batch.reward + gamma * batch.discount * (next_q - jnp.exp(log_alpha) * next_logp)
    q = critic.apply(critic_params, batch.obs, batch.action)
    return 0.5 * jnp.sum(jnp.mean((q - jax.lax.stop_gradient(target)) ** 2, axis=-1))


def actor_loss(actor_params, critic_params, log_alpha, batch: Transition, rng, *, actor: Actor,
               critic: DoubleCritic):
    """``mean(α log π(a|s) - min_i Q_i(s, a))``, ``a ~ π(s)``; also returns ``log π`` for the α loss."""
    mean, log_std = actor.apply(actor_params, batch.obs)
    action, logp = sample_tanh_gaussian(mean, log_std, rng)
    q = jnp.min(critic.apply(critic_params, batch.obs, action), axis=0)
    return jnp.mean(jnp.exp(log_alpha) * logp - q), logp


def alpha_loss(log_alpha, logp, target_entropy: float):
    """Entropy temperature loss ``-mean(log α (log π + H_target))``."""
    return -jnp.mean(log_alpha * jax.lax.stop_gradient(logp + target_entropy))
