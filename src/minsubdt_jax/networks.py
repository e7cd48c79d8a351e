"""Networks shared by the SAC behaviour policies (:mod:`minsubdt_jax.behavior`) and the agents
(:mod:`minsubdt_jax.agents`): the ReLU MLP torso, the Q-function and its ``nn.vmap``-ed ensemble, and the
(tanh-squashed) Gaussian's samples and log-densities. ``dtype`` (``--precision bf16``: bfloat16) is the dtype of the
matmuls; parameters stay float32 and every output is float32."""

from __future__ import annotations

from typing import Any, Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp


class MLP(nn.Module):
    """ReLU layers of widths ``hidden``; ``dtype``: the matmuls' dtype (bfloat16 for --precision bf16), parameters
    float32."""

    hidden: Sequence[int]
    dtype: Any = None

    @nn.compact
    def __call__(self, x):
        for h in self.hidden:
            x = nn.relu(nn.Dense(h, dtype=self.dtype)(x))
        return x


def f32(x):
    return x.astype(jnp.float32)


class Critic(nn.Module):
    """``(states [..., obs], actions [..., act]) -> Q [...]``."""

    hidden: Sequence[int]
    dtype: Any = None

    @nn.compact
    def __call__(self, states, actions):
        h = MLP(self.hidden, self.dtype)(jnp.concatenate([states, actions], -1))
        return f32(nn.Dense(1, dtype=self.dtype)(h))[..., 0]


class Critics(nn.Module):
    """``num`` independent :class:`Critic` s in one module (``nn.vmap`` over their parameters): ``Q [num, ...]``."""

    hidden: Sequence[int]
    num: int = 2
    dtype: Any = None
    # the ensemble's parameter name (its path seeds its initialisation): flax's own by default; the SAC trainer keeps
    # the name its critics always had, so it starts from the same parameters
    member_name: str | None = None

    @nn.compact
    def __call__(self, states, actions):
        ensemble = nn.vmap(Critic, variable_axes={"params": 0}, split_rngs={"params": True}, in_axes=None,
                           out_axes=0, axis_size=self.num)
        return ensemble(self.hidden, self.dtype, name=self.member_name)(states, actions)


def gaussian_log_prob(x, mean, log_std):
    """Log-density ``[...]`` of a diagonal Gaussian at ``x [..., act]``, summed over the action dims."""
    return jnp.sum(-0.5 * ((x - mean) / jnp.exp(log_std)) ** 2 - log_std - 0.5 * jnp.log(2 * jnp.pi), -1)


def tanh_correction(u):
    """``sum log(1 - tanh(u)^2)`` over the action dims, as ``2 (log 2 - u - softplus(-2u))`` (stable)."""
    return jnp.sum(2.0 * (jnp.log(2.0) - u - jax.nn.softplus(-2.0 * u)), -1)


def gaussian_sample(rng, mean, log_std):
    """A reparameterised sample ``mean + std * eps`` of the pre-tanh Gaussian."""
    return mean + jnp.exp(log_std) * jax.random.normal(rng, mean.shape)


def tanh_gaussian_sample(rng, mean, log_std):
    """``(actions [..., act], log_prob [...])``: a reparameterised sample of ``tanh(N(mean, std))`` and its
    log-density, with the tanh's change of variables ``log(1 - tanh(u)^2) = 2 (log 2 - u - softplus(-2u))``."""
    u = gaussian_sample(rng, mean, log_std)
    return jnp.tanh(u), gaussian_log_prob(u, mean, log_std) - tanh_correction(u)
