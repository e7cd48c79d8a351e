"""Behaviour cloning loss of the MLP policy."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ...data import Batch
from .networks import MLPPolicy


def bc_loss(model: MLPPolicy, params, batch: Batch) -> jax.Array:
    """Mean squared error between the policy's action and the dataset's, at the last (always real) token of each
    window (windows of length 1: one ``(s, a)`` pair per row, drawn uniformly over the dataset's steps)."""
    pred = model.apply(params, batch.states[:, -1])
    return jnp.mean((pred - batch.actions[:, -1]) ** 2)
