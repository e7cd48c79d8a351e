"""The Decision Transformer's training loss."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ...data import Batch
from .networks import DecisionTransformer


def action_loss(model: DecisionTransformer, params, batch: Batch, rng) -> jax.Array:
    """Mean squared action error over real (unpadded) tokens ``batch.mask [B, K]``, dropout on."""
    pred = model.apply(params, batch.states, batch.actions, batch.returns_to_go, batch.timesteps, batch.mask,
                       deterministic=False, rngs={"dropout": rng})
    err = jnp.mean((pred - batch.actions) ** 2, axis=-1)
    return jnp.sum(err * batch.mask) / jnp.maximum(jnp.sum(batch.mask), 1)
