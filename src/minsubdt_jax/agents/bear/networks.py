"""BEAR's behaviour model: a conditional VAE of the data's actions (d4rl_evaluations ``bear/rlkit/torch/sac/
policies.py``, ``VAEPolicy``): 750 x 750 encoder and decoder, latent dimension 2|A|, encoder log-std clamped to
[-4, 15], decoded latents drawn from N(0, 1) clipped to [-0.5, 0.5]."""

from __future__ import annotations

from typing import Any, Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

from ...networks import MLP
from ...networks import f32


class VAE(nn.Module):
    """``(states, actions, rng) -> (reconstruction, mean, std)``; :meth:`decode` gives ``(actions, pre_tanh)``."""

    act_dim: int
    hidden: Sequence[int] = (750, 750)
    dtype: Any = None  # the matmuls' (--precision bf16); parameters and outputs float32

    def setup(self):
        self.encoder = MLP(self.hidden, self.dtype)
        self.enc_mean = nn.Dense(2 * self.act_dim, dtype=self.dtype)
        self.enc_log_std = nn.Dense(2 * self.act_dim, dtype=self.dtype)
        self.decoder = MLP(self.hidden, self.dtype)
        self.dec_out = nn.Dense(self.act_dim, dtype=self.dtype)

    def __call__(self, states, actions, rng):
        h = self.encoder(jnp.concatenate([states, actions], -1))
        mean, std = f32(self.enc_mean(h)), jnp.exp(jnp.clip(f32(self.enc_log_std(h)), -4.0, 15.0))
        z = mean + std * jax.random.normal(rng, mean.shape)
        return self.decode(states, z)[0], mean, std

    def decode(self, states, z):
        pre_tanh = f32(self.dec_out(self.decoder(jnp.concatenate([states, z], -1))))
        return jnp.tanh(pre_tanh), pre_tanh


def decode_samples(vae: VAE, params, rng, states, n: int):
    """``(actions, pre_tanh) [n, B, act]``: ``n`` decoded actions per state from clipped N(0, 1) latents."""
    z = jnp.clip(jax.random.normal(rng, (n, *states.shape[:-1], 2 * vae.act_dim)), -0.5, 0.5)
    return vae.apply(params, jnp.broadcast_to(states, (n, *states.shape)), z, method=VAE.decode)
