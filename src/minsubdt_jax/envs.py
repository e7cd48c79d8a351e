"""MJX environments (brax, ``backend='mjx'``), batched rollouts and normalised scores.

Normalised scores are in :mod:`minsubdt_jax.references`. One rollout program serves dataset generation and
evaluation: ``make_rollout`` returns a jitted
``run(policy_params, policy_carry, rng)`` that steps ``num_episodes`` environments in parallel inside one
``lax.while_loop`` over time (it stops early once every episode has ended), records every transition, and
keeps termination apart from time-out (``horizon`` steps without termination).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from .parallel import shard_batch


@dataclass(frozen=True)
class EnvSpec:
    """Static facts about one environment.

    ``x_velocity_index`` / ``z_velocity_index`` index the observation vector (gym/D4RL layout: ``qpos[1:]``
    then ``qvel``), so cost metrics can be read from any D4RL-layout dataset as well as from our rollouts.
    ``reset_obs0`` is ``obs[0]`` in a reset state (torso height for hopper and walker, the root's z offset for
    halfcheetah), in brax MJX and in gym alike: it tells apart datasets of envs with the same shapes.
    """

    name: str
    brax_name: str
    obs_dim: int
    act_dim: int
    x_velocity_index: int
    z_velocity_index: int | None
    reset_obs0: float

    @property
    def terminates(self) -> bool:
        """Episodes end early when the body falls (hopper, walker); halfcheetah runs to the time limit."""
        return self.name in ("hopper", "walker")


# reset_obs0 measured as the mean obs[0] of 64 brax MJX resets: 1.25 ± 0.003 (hopper, walker), 0.00 ± 0.06
# (halfcheetah); gym's resets (D4RL) have the same values.
ENVS = {
    "hopper": EnvSpec("hopper", "hopper", 11, 3, 5, 6, 1.25),
    "walker": EnvSpec("walker", "walker2d", 17, 6, 8, 9, 1.25),
    "halfcheetah": EnvSpec("halfcheetah", "halfcheetah", 17, 6, 8, None, 0.0),
}
_ALIASES = {"walker2d": "walker", "half_cheetah": "halfcheetah", "cheetah": "halfcheetah"}

def env_spec(name: str) -> EnvSpec:
    """The :class:`EnvSpec` for ``hopper``, ``walker`` (``walker2d``) or ``halfcheetah``."""
    key = _ALIASES.get(name, name)
    if key not in ENVS:
        raise ValueError(f"unknown env {name!r}; choose one of {sorted(ENVS)} (aliases: {sorted(_ALIASES)})")
    return ENVS[key]


def check_dataset(env: str, observations, actions, lengths, recorded_env: str | None = None) -> None:
    """Raise ValueError unless episodes ``observations [N, T, obs]``, ``actions [N, T, act]`` can come from ``env``.

    The shapes must be the env's. Where several envs share them (walker and halfcheetah), the episodes' first
    states must be nearer this env's reset state than another's (median ``obs[0]`` against ``reset_obs0``).
    ``recorded_env`` (the env a file of ours names) must be ``env``."""
    spec = env_spec(env)
    if recorded_env is not None and env_spec(recorded_env) != spec:
        raise ValueError(f"the dataset was recorded in {recorded_env}, not in {spec.name}: pass --env {recorded_env}")
    shape = (observations.shape[-1], actions.shape[-1])
    if shape != (spec.obs_dim, spec.act_dim):
        fits = [s.name for s in ENVS.values() if (s.obs_dim, s.act_dim) == shape]
        raise ValueError(f"the dataset has observations of size {shape[0]} and actions of size {shape[1]}; {spec.name} "
                         f"has {spec.obs_dim} and {spec.act_dim}" + (f" (it fits {', '.join(fits)})" if fits else ""))
    start = float(np.median(np.asarray(observations)[np.asarray(lengths) > 0, 0, 0]))
    same = [s for s in ENVS.values() if (s.obs_dim, s.act_dim) == shape]
    nearest = min(same, key=lambda s: abs(start - s.reset_obs0))
    if nearest != spec:
        raise ValueError(f"the dataset's episodes start at obs[0] = {start:.3f} (median), a {nearest.name} reset state "
                         f"({nearest.reset_obs0}), not a {spec.name} one ({spec.reset_obs0}): is it a {nearest.name} "
                         f"dataset? (pass --env {nearest.name})")


@functools.lru_cache(maxsize=None)
def make_env(name: str):
    """The brax environment for ``name`` with MJX physics (cached: one instance, one compile per shape)."""
    from brax import envs as brax_envs

    if jax.process_count() == 1:
        return brax_envs.get_environment(env_spec(name).brax_name, backend="mjx")
    # mujoco-mjx puts the model on jax.devices()[0], which in a multi-process job belongs to process 0 alone
    # (another process could neither read it nor compile a rollout that closes over it): place it on this
    # process's first device instead.
    from unittest import mock

    from brax.io import mjcf

    put_model = functools.partial(mjcf.mjx.put_model, device=jax.local_devices()[0])
    with mock.patch.object(mjcf.mjx, "put_model", put_model):
        return brax_envs.get_environment(env_spec(name).brax_name, backend="mjx")


@struct.dataclass
class Rollout:
    """Recorded episodes, padded to ``horizon`` (entries past ``lengths`` are 0).

    observations ``[N, H, obs]`` (the state each action was taken in), actions ``[N, H, act]``,
    rewards ``[N, H]``, lengths ``[N]``, terminated ``[N]`` (ended by termination, not by time-out),
    and the physics state each action was taken in: qpos ``[N, H, nq]``, qvel ``[N, H, nv]``.
    """

    observations: jax.Array
    actions: jax.Array
    rewards: jax.Array
    lengths: jax.Array
    terminated: jax.Array
    qpos: jax.Array
    qvel: jax.Array


# policy(params, carry, obs [N, obs], prev_reward [N], t, rng) -> (carry, action [N, act])
Policy = Callable[[Any, Any, jax.Array, jax.Array, jax.Array, jax.Array], tuple[Any, jax.Array]]


@functools.lru_cache(maxsize=32)
def make_rollout(env: str, policy: Policy, num_episodes: int, horizon: int, mesh=None):
    """Cached, jitted ``run(policy_params, policy_carry, rng) -> Rollout`` for ``num_episodes`` parallel episodes.

    With a ``mesh`` (:func:`minsubdt_jax.parallel.make_mesh`, its size dividing ``num_episodes``) the episodes,
    their policy carry and the recorded buffers are split over its devices; every episode's computation is
    unchanged.

    Actions are clipped to ``[-1, 1]`` (recorded clipped). An ended episode's physics state is frozen and
    its later entries are zero. ``policy_params`` and ``policy_carry`` are traced, so one compile serves
    every parameter value.
    """
    brax_env = make_env(env)
    spec = env_spec(env)
    n, H = int(num_episodes), int(horizon)
    if n < 1 or H < 1:
        raise ValueError(f"num_episodes and horizon must be >= 1, got {n} and {H}")
    if mesh is not None and n % mesh.size:
        raise ValueError(f"num_episodes ({n}) must be divisible by the mesh size ({mesh.size})")

    def run(policy_params, policy_carry, rng):
        rng, reset_rng = jax.random.split(rng)
        state = shard_batch(jax.vmap(brax_env.reset)(jax.random.split(reset_rng, n)), mesh)
        policy_carry = shard_batch(policy_carry, mesh)
        pipe = state.pipeline_state
        buffers = shard_batch((
            jnp.zeros((H, n, spec.obs_dim)),
            jnp.zeros((H, n, spec.act_dim)),
            jnp.zeros((H, n)),
            jnp.zeros((H,) + pipe.qpos.shape),
            jnp.zeros((H,) + pipe.qvel.shape),
        ), mesh, axis=1)
        init = (0, state, policy_carry, jnp.zeros(n, bool), jnp.zeros(n, bool), jnp.zeros(n), rng, buffers,
                jnp.zeros(n, jnp.int32))

        def cond(c):
            return (c[0] < H) & ~jnp.all(c[3])

        def body(c):
            t, state, pcarry, done, terminated, prev_r, rng, (obs_b, act_b, rew_b, qpos_b, qvel_b), length = c
            rng, key = jax.random.split(rng)
            pcarry, action = policy(policy_params, pcarry, state.obs, prev_r, t, key)
            action = jnp.clip(action, -1.0, 1.0)
            nstate = jax.vmap(brax_env.step)(state, action)
            alive = ~done
            reward = jnp.where(alive, nstate.reward, 0.0)
            obs_b = obs_b.at[t].set(jnp.where(alive[:, None], state.obs, 0.0))
            act_b = act_b.at[t].set(jnp.where(alive[:, None], action, 0.0))
            rew_b = rew_b.at[t].set(reward)
            qpos_b = qpos_b.at[t].set(jnp.where(alive[:, None], state.pipeline_state.qpos, 0.0))
            qvel_b = qvel_b.at[t].set(jnp.where(alive[:, None], state.pipeline_state.qvel, 0.0))
            ended = alive & (nstate.done > 0)
            state = jax.tree.map(lambda old, new: jnp.where(_bcast(done, old), old, new), state, nstate)
            return (t + 1, state, pcarry, done | ended, terminated | ended, reward, rng,
                    (obs_b, act_b, rew_b, qpos_b, qvel_b), length + alive)

        c = jax.lax.while_loop(cond, body, init)
        obs_b, act_b, rew_b, qpos_b, qvel_b = (b.swapaxes(0, 1) for b in c[7])
        return shard_batch(Rollout(observations=obs_b, actions=act_b, rewards=rew_b, lengths=c[8],
                                   terminated=c[4], qpos=qpos_b, qvel=qvel_b), mesh)

    return jax.jit(run)


def _bcast(mask, x):
    return mask.reshape(mask.shape + (1,) * (x.ndim - 1))


def random_policy(params, carry, obs, prev_reward, t, rng):
    """Uniform random actions in ``[-1, 1]``; ``params`` is the action dimension's template ``[act]``."""
    return carry, jax.random.uniform(rng, (obs.shape[0],) + params.shape, minval=-1.0, maxval=1.0)
