"""Jitted samplers: fixed-length context windows for Decision Transformer training, and transitions
``(s, a, r, s', done)`` for the critic agents.

Windows as in the official DT code: a trajectory is drawn with probability proportional to its length (as its
``np.random.choice(p=...)``, by inverting the integer cumulative weights: episodes of weight 0, another dataset's
in a program over several, are never drawn and do not change the draws of the others), a start step uniformly
within it, and the window ``[start, start + K)`` is cut at the trajectory's end and
left-padded to K. The mask is computed from the number of real tokens before any padding is written.

Transitions as D4RL's ``qlearning_dataset``: every step with a next state in its episode, uniformly; the last step
of an episode only where it ends the episode for the critic (``last_done``: a termination, or every episode for a
reward that ends with the episode, MinSubDT's surrogate), and then with ``done = 1``. A time-out's last step has
no next state in the data and is left out, so time-outs bootstrap.
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
    """Device arrays the samplers read: states ``[N, T, obs]`` (normalised), actions ``[N, T, act]``,
    returns_to_go ``[N, T]`` (already scaled; ``[N, T, K]`` for a token per metric), lengths ``[N]``, weights ``[N]`` int32 (an episode's windows are
    drawn in proportion to it: its length, or 0 for an episode this model does not train on); for
    transitions, the per-step rewards ``[N, T]`` (scaled alike) and ``last_done [N]`` (1.0: the last step is a
    transition with ``done``; 0.0: it is left out)."""

    states: jax.Array
    actions: jax.Array
    returns_to_go: jax.Array
    lengths: jax.Array
    weights: jax.Array
    rewards: jax.Array
    last_done: jax.Array


@struct.dataclass
class Batch:
    """A batch of windows: states ``[B, K, obs]``, actions ``[B, K, act]``, returns_to_go ``[B, K]`` (or ``[B, K, R]``),
    timesteps ``[B, K]`` int32, mask ``[B, K]`` bool (True on real tokens; padding is on the left)."""

    states: jax.Array
    actions: jax.Array
    returns_to_go: jax.Array
    timesteps: jax.Array
    mask: jax.Array


@struct.dataclass
class Transitions:
    """A batch of transitions: states, next_states ``[B, obs]``, actions ``[B, act]``, rewards and done ``[B]``
    (1.0: no bootstrap from ``next_states``)."""

    states: jax.Array
    actions: jax.Array
    rewards: jax.Array
    next_states: jax.Array
    done: jax.Array


def sampler_data(dataset: Trajectories, returns_to_go, state_mean, state_std, rewards=None,
                 last_done=None) -> SamplerData:
    """Device-side arrays for :func:`sample_batch` and :func:`sample_transitions`; ``returns_to_go [N, T]`` as
    the model will see them, ``rewards [N, T]`` likewise (default: the dataset's), ``last_done [N]`` (default:
    the dataset's terminations)."""
    rtg = np.asarray(returns_to_go, np.float32)
    rewards = dataset.rewards if rewards is None else np.asarray(rewards, np.float32)
    last_done = dataset.terminals if last_done is None else np.asarray(last_done)
    if rtg.shape[:2] != dataset.rewards.shape or rtg.ndim > 3 or rewards.shape != dataset.rewards.shape:
        raise ValueError(f"returns_to_go must have shape {dataset.rewards.shape} (or [N, T, K]: one per metric) and "
                         f"rewards {dataset.rewards.shape}, got {rtg.shape} and {rewards.shape}")
    states = (dataset.observations - state_mean) / state_std
    states[~dataset.valid_mask()] = 0.0
    return SamplerData(
        states=jnp.asarray(states, jnp.float32),
        actions=jnp.asarray(dataset.actions, jnp.float32),
        returns_to_go=jnp.asarray(rtg),
        lengths=jnp.asarray(dataset.lengths, jnp.int32),
        weights=jnp.asarray(dataset.lengths, jnp.int32),
        rewards=jnp.asarray(np.where(dataset.valid_mask(), rewards, 0.0), jnp.float32),
        last_done=jnp.asarray(last_done, jnp.float32),
    )


def draw_episodes(rng, weights, batch_size: int):
    """``[batch_size]`` episode indices drawn with probability ``weights / weights.sum()`` (``weights [N]``
    int32): a uniform integer below the total, located in the cumulative weights. Episodes of weight 0 are never
    drawn, and appending or prepending them shifts the indices but leaves the draws of the others unchanged."""
    cum = jnp.cumsum(weights)
    r = jax.random.randint(rng, (batch_size,), 0, cum[-1])
    return jnp.searchsorted(cum, r, side="right").astype(jnp.int32)


@partial(jax.jit, static_argnames=("batch_size", "context_len"))
def sample_batch(rng, data: SamplerData, batch_size: int, context_len: int) -> Batch:
    """Sample ``batch_size`` windows of ``context_len`` steps (see module docstring)."""
    k_traj, k_start = jax.random.split(rng)
    traj = draw_episodes(k_traj, data.weights, batch_size)  # P(i) ∝ length_i
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
        returns_to_go=jnp.where(mask.reshape(mask.shape + (1,) * (data.returns_to_go.ndim - 2)),
                                data.returns_to_go[rows, t], 0.0),
        timesteps=t.astype(jnp.int32),
        mask=mask,
    )


@partial(jax.jit, static_argnames=("batch_size",))
def sample_transitions(rng, data: SamplerData, batch_size: int) -> Transitions:
    """Sample ``batch_size`` transitions uniformly over the data's transitions (see module docstring): an episode
    with probability proportional to its ``length - 1 + last_done`` transitions, a step uniformly among them."""
    k_traj, k_step = jax.random.split(rng)
    # [N] transitions per episode (0 for a timed-out 1-step episode, and for an episode of weight 0)
    count = jnp.where(data.weights > 0, data.lengths - 1 + data.last_done.astype(jnp.int32), 0)
    traj = draw_episodes(k_traj, count, batch_size)
    n = count[traj].astype(jnp.float32)
    t = jnp.minimum(jnp.floor(jax.random.uniform(k_step, (batch_size,)) * n), n - 1).astype(jnp.int32)
    done = t == data.lengths[traj] - 1  # sampled only where last_done
    nxt = jnp.minimum(t + 1, data.states.shape[1] - 1)
    return Transitions(states=data.states[traj, t], actions=data.actions[traj, t], rewards=data.rewards[traj, t],
                       next_states=data.states[traj, nxt], done=done.astype(jnp.float32))
