"""The critic agents' networks, one family for all of them (as unifloral's), on the shared MLP torso and Q-function
ensemble (:mod:`minsubdt_jax.networks`, with the Gaussian's samples and log-densities): a state-value net, and three
actors: deterministic (TD3+BC), a Gaussian with a tanh on
its mean and a state-independent log-std (IQL's ``NormalTanhPolicy`` without a squashed distribution), and a
tanh-squashed Gaussian with a state-dependent log-std (SAC, CQL). Inputs are normalised states ``[B, obs]`` and
actions in ``[-1, 1]``; the leading dimensions may be anything. ``dtype`` (``--precision bf16``: bfloat16) is the
dtype of their matmuls; parameters stay float32 and every output is float32, so losses are computed in float32."""

from __future__ import annotations

from typing import Any, Sequence

import flax.linen as nn
import jax.numpy as jnp

from ..networks import MLP, f32, gaussian_log_prob, tanh_correction


class Value(nn.Module):
    """``states [..., obs] -> V [...]``."""

    hidden: Sequence[int]
    dtype: Any = None

    @nn.compact
    def __call__(self, states):
        return f32(nn.Dense(1, dtype=self.dtype)(MLP(self.hidden, self.dtype)(states)))[..., 0]


class DeterministicActor(nn.Module):
    """``states -> actions = tanh(MLP(states))`` (TD3+BC)."""

    act_dim: int
    hidden: Sequence[int]
    dtype: Any = None

    @nn.compact
    def __call__(self, states):
        return jnp.tanh(f32(nn.Dense(self.act_dim, dtype=self.dtype)(MLP(self.hidden, self.dtype)(states))))


class TanhMeanGaussianActor(nn.Module):
    """IQL's actor (ikostrikov/implicit_q_learning ``policy.NormalTanhPolicy``, ``tanh_squash_distribution=False``):
    ``states -> (mean = tanh(Dense(MLP)), log_std)``, the log-std one trained vector clipped to ``[-5, 2]``."""

    act_dim: int
    hidden: Sequence[int]
    dtype: Any = None

    @nn.compact
    def __call__(self, states):
        mean = jnp.tanh(f32(nn.Dense(self.act_dim, dtype=self.dtype)(MLP(self.hidden, self.dtype)(states))))
        log_std = self.param("log_std", nn.initializers.zeros, (self.act_dim,))
        return mean, jnp.broadcast_to(jnp.clip(log_std, -5.0, 2.0), mean.shape)


class TanhGaussianActor(nn.Module):
    """The SAC/CQL actor (CORL ``TanhGaussianPolicy``): ``states -> (mean, log_std)`` of the pre-tanh Gaussian, with
    ``log_std = m * head + o`` for trained scalars ``m = 1``, ``o = -1`` at init, clipped to ``[-20, 2]``; with
    ``log_std_range = (lo, hi)`` instead ``lo + (hi - lo) (tanh(head) + 1) / 2`` (BRAC's policies, ``[-5, 0]``)."""

    act_dim: int
    hidden: Sequence[int]
    log_std_range: tuple | None = None
    dtype: Any = None

    @nn.compact
    def __call__(self, states):
        out = f32(nn.Dense(2 * self.act_dim, dtype=self.dtype)(MLP(self.hidden, self.dtype)(states)))
        mean, raw = out[..., :self.act_dim], out[..., self.act_dim:]
        if self.log_std_range is not None:
            lo, hi = self.log_std_range
            return mean, lo + 0.5 * (hi - lo) * (jnp.tanh(raw) + 1.0)
        m = self.param("log_std_multiplier", nn.initializers.ones, ())
        o = self.param("log_std_offset", lambda k, s: -jnp.ones(s), ())
        return mean, jnp.clip(m * raw + o, -20.0, 2.0)


def tanh_gaussian_log_prob(actions, mean, log_std, margin: float = 1e-3):
    """Log-density ``[...]`` of ``tanh(N(mean, std))`` at ``actions [..., act]``, clipped ``margin`` inside
    ``[-1, 1]`` first (BRAC's ``clip_eps``; the data's actions may sit on the bounds)."""
    u = jnp.arctanh(jnp.clip(actions, -1.0 + margin, 1.0 - margin))
    return gaussian_log_prob(u, mean, log_std) - tanh_correction(u)


def repeat(x, n: int):
    """``[n, *x.shape]``: ``n`` copies of ``x`` on a new leading axis (samples per state)."""
    return jnp.broadcast_to(x, (n, *x.shape))
