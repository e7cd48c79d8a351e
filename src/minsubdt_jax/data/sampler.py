"""Jitted sampler of fixed-length context windows for Decision Transformer training.

As in the official DT code: a trajectory is drawn with probability proportional to its length, a start
step uniformly within it, and the window ``[start, start + K)`` is cut at the trajectory's end and
left-padded to K. The mask is computed from the number of real tokens before any padding is written.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from .dataset import Trajectories


@struct.dataclass
class SamplerData:
    """Device arrays the sampler reads: states ``[N, T, obs]`` (normalised), actions ``[N, T, act]``,
    returns_to_go ``[N, T]`` (already scaled), lengths ``[N]``, and log sampling weights ``[N]``."""

    states: jax.Array
    actions: jax.Array
    returns_to_go: jax.Array
    lengths: jax.Array
    logits: jax.Array


@struct.dataclass
class Batch:
    """A batch of windows: states ``[B, K, obs]``, actions ``[B, K, act]``, returns_to_go ``[B, K]``,
    timesteps ``[B, K]`` int32, mask ``[B, K]`` bool (True on real tokens; padding is on the left)."""

    states: jax.Array
    actions: jax.Array
    returns_to_go: jax.Array
    timesteps: jax.Array
    mask: jax.Array


def sampler_data(dataset: Trajectories, returns_to_go, state_mean, state_std) -> SamplerData:
    """Device-side arrays for :func:`sample_batch`; ``returns_to_go [N, T]`` as the model will see them."""
    rtg = np.asarray(returns_to_go, np.float32)
    if rtg.shape != dataset.rewards.shape:
        raise ValueError(f"returns_to_go must have shape {dataset.rewards.shape}, got {rtg.shape}")
    states = (dataset.observations - state_mean) / state_std
    states[~dataset.valid_mask()] = 0.0
    return SamplerData(
        states=jnp.asarray(states, jnp.float32),
        actions=jnp.asarray(dataset.actions, jnp.float32),
        returns_to_go=jnp.asarray(rtg),
        lengths=jnp.asarray(dataset.lengths, jnp.int32),
        logits=jnp.log(jnp.asarray(dataset.lengths, jnp.float32)),
    )


@partial(jax.jit, static_argnames=("batch_size", "context_len"))
def sample_batch(rng, data: SamplerData, batch_size: int, context_len: int) -> Batch:
    """Sample ``batch_size`` windows of ``context_len`` steps (see module docstring)."""
    k_traj, k_start = jax.random.split(rng)
    traj = jax.random.categorical(k_traj, data.logits, shape=(batch_size,))  # P(i) ∝ length_i
    length = data.lengths[traj]
    start = jnp.minimum(jnp.floor(jax.random.uniform(k_start, (batch_size,)) * length), length - 1).astype(jnp.int32)
    n_real = jnp.minimum(context_len, length - start)  # real tokens in the window, before padding
    j = jnp.arange(context_len)[None, :]
    mask = j >= (context_len - n_real)[:, None]
    t = jnp.where(mask, start[:, None] + j - (context_len - n_real)[:, None], 0)
    rows = traj[:, None]
    return Batch(
        states=jnp.where(mask[..., None], data.states[rows, t], 0.0),
        actions=jnp.where(mask[..., None], data.actions[rows, t], 0.0),
        returns_to_go=jnp.where(mask, data.returns_to_go[rows, t], 0.0),
        timesteps=t.astype(jnp.int32),
        mask=mask,
    )
