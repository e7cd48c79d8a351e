"""Behaviour cloning loss of the MLP policy."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ...data import Batch
from .networks import MLPPolicy


def policy_input(batch: Batch, return_dim: int) -> jax.Array:
    """``[B, obs (+ R)]``: the last (always real) token's state of each window, and for a return-conditioned policy
    (RvS, PEDA's MORvS) its return token ``[R]`` (scaled as the model sees it)."""
    if not return_dim:
        return batch.states[:, -1]
    return jnp.concatenate([batch.states[:, -1], batch.returns_to_go[:, -1].reshape(-1, return_dim)], -1)


def bc_loss(model: MLPPolicy, params, batch: Batch, return_dim: int = 0) -> jax.Array:
    """Mean squared error between the policy's action and the dataset's, at the last token of each window
    (windows of length 1: one ``(s, a)`` pair per row, drawn uniformly over the dataset's steps)."""
    pred = model.apply(params, policy_input(batch, return_dim))
    return jnp.mean((pred - batch.actions[:, -1]) ** 2)
