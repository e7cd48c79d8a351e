"""The Decision Transformer agent (MinSubDT, DT and the DT-architecture BC train this one agent on different
return tokens: :mod:`minsubdt_jax.methods`)."""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from ..base import StepAgent
from .losses import action_loss
from .networks import DecisionTransformer
from .policy import dt_policy, empty_context, return_shape


@dataclass(frozen=True)
class DTAgent(StepAgent):
    """A DT of the given size for ``obs_dim``/``act_dim`` and episodes of up to ``max_timestep`` steps."""

    obs_dim: int
    act_dim: int
    context_len: int
    embed_dim: int
    n_layers: int
    n_heads: int
    dropout: float
    max_timestep: int
    precision: str = "f32"  # f32 | tf32 (TF32 matmuls where the device has them) | bf16 (bfloat16 matmuls)
    return_dim: int = 0  # 0: one return token per step [.., K]; R > 0: R returns per step [.., K, R] (per metric)

    @property
    def model(self) -> DecisionTransformer:
        return DecisionTransformer(act_dim=self.act_dim, embed_dim=self.embed_dim, n_layers=self.n_layers,
                                   n_heads=self.n_heads, dropout=self.dropout, max_timestep=self.max_timestep,
                                   dtype=jnp.bfloat16 if self.precision == "bf16" else None)

    def init_params(self, key):
        K = self.context_len
        return self.model.init(key, jnp.zeros((1, K, self.obs_dim)), jnp.zeros((1, K, self.act_dim)),
                               jnp.zeros((1, K) + return_shape(self.return_dim)), jnp.zeros((1, K), jnp.int32),
                               jnp.ones((1, K), bool))

    def loss(self, params, batch, rng):
        if self.precision == "tf32":  # read when the step is traced
            with jax.default_matmul_precision("tensorfloat32"):
                return action_loss(self.model, params, batch, rng)
        return action_loss(self.model, params, batch, rng)

    @property
    def policy(self):
        return dt_policy(self.model)

    def initial_carry(self, n: int):
        return empty_context(n, self.context_len, self.obs_dim, self.act_dim, self.return_dim)


def make_dt_agent(cfg, obs_dim: int, act_dim: int, max_timestep: int, return_dim: int = 0) -> DTAgent:
    """``return_dim``: 0 for one return token per step, K for a vector method's one per cost metric."""
    return DTAgent(obs_dim, act_dim, cfg.context_len, cfg.embed_dim, cfg.n_layers, cfg.n_heads, cfg.dropout,
                   max_timestep, cfg.precision, return_dim)


def train_step_bytes(cfg, n_models: int) -> int:
    """About the memory one train step of ``n_models`` DTs holds (float32): per layer and window, the activations
    kept for the backward pass, ~16 ``[3K, d]`` tensors and ~4 ``[heads, 3K, 3K]`` (attention logits, weights,
    their dropout and gradient), twice over for their gradients. An over-estimate: 1.3-1.8x XLA's own temporary
    memory for one step at study, paper, study with context 100 and study with batch 512 (measured 2026-12-06);
    what matters is the order: the attention grows with the context squared."""
    T = 3 * cfg.context_len
    per_layer = 16 * T * cfg.embed_dim + 4 * cfg.n_heads * T * T
    return 2 * 4 * n_models * cfg.batch_size * cfg.n_layers * per_layer
