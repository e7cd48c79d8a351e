"""MJX physics: the env as pure JAX functions (``reset``, ``step``) and a batched rollout of any policy in one
jitted ``lax.while_loop`` over time. The rules are :mod:`minsubdt_jax.envs.rules`; with ``dynamics='brax'`` this is
brax's own MJX env (``backend='mjx'``), step for step (tested against it)."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp
from flax import struct

from ..parallel import shard_batch
from .rules import TORSO, env_rules, forward_position, import_mjx, mj_model, observe, reset_state, step_outcome
from .spec import Policy, Rollout, env_spec


@struct.dataclass
class EnvState:
    """One env (or a batch, with leading axes): its MJX ``data``, the observation of its state, the reward and
    ``done`` (1.0 = terminated) of the step that led to it."""

    data: object
    obs: jax.Array
    reward: jax.Array
    done: jax.Array


@functools.lru_cache(maxsize=None)
def put_model(env: str, dynamics: str):
    """The MJX model of :func:`~minsubdt_jax.envs.rules.mj_model`, placed on this process's first device (in a
    multi-process job ``jax.devices()[0]`` belongs to process 0 alone)."""
    mjx = import_mjx()

    with jax.ensure_compile_time_eval():  # concrete arrays even when first asked for inside a trace
        return mjx.put_model(mj_model(env, dynamics), device=jax.local_devices()[0])


@dataclass(frozen=True)
class MjxEnv:
    """``reset(key) -> EnvState`` and ``step(state, action) -> EnvState`` for one env; ``vmap`` them for a batch."""

    env: str
    dynamics: str = "brax"

    @property
    def rules(self):
        return env_rules(self.env, self.dynamics)

    def reset(self, key) -> EnvState:
        mjx = import_mjx()

        model = put_model(self.env, self.dynamics)
        qpos, qvel = reset_state(self.rules, model.qpos0, key)
        data = mjx.forward(model, mjx.make_data(model).replace(qpos=qpos, qvel=qvel))
        obs = observe(self.rules, data.qpos, data.qvel, data.xpos[TORSO])
        return EnvState(data=data, obs=obs, reward=jnp.zeros(()), done=jnp.zeros(()))

    def step(self, state: EnvState, action) -> EnvState:
        mjx = import_mjx()

        model, rules = put_model(self.env, self.dynamics), self.rules
        x_before = forward_position(rules, state.data.qpos, state.data.xpos[TORSO])
        data = state.data.replace(ctrl=action)
        data = jax.lax.scan(lambda d, _: (mjx.step(model, d), None), data, None, length=rules.frame_skip)[0]
        reward, done = step_outcome(rules, x_before, data.qpos, data.qvel, data.xpos[TORSO], action)
        obs = observe(rules, data.qpos, data.qvel, data.xpos[TORSO])
        return EnvState(data=data, obs=obs, reward=reward, done=done.astype(jnp.float32))


def make_mjx_rollout(env: str, policy: Policy, num_episodes: int, horizon: int, mesh=None, dynamics: str = "brax"):
    """Jitted ``run(policy_params, policy_carry, rng) -> Rollout`` for ``num_episodes`` parallel episodes in MJX.

    With a ``mesh`` the episodes, their policy carry and the recorded buffers are split over its devices. Actions
    are clipped to ``[-1, 1]`` (recorded clipped). An ended episode's physics state is frozen and its later
    entries are zero; the loop stops once every episode has ended."""
    mjx_env = MjxEnv(env_spec(env).name, dynamics)
    spec = env_spec(env)
    n, H = int(num_episodes), int(horizon)

    def run(policy_params, policy_carry, rng):
        rng, reset_rng = jax.random.split(rng)
        state = shard_batch(jax.vmap(mjx_env.reset)(jax.random.split(reset_rng, n)), mesh)
        policy_carry = shard_batch(policy_carry, mesh)
        buffers = shard_batch((
            jnp.zeros((H, n, spec.obs_dim)),
            jnp.zeros((H, n, spec.act_dim)),
            jnp.zeros((H, n)),
            jnp.zeros((H,) + state.data.qpos.shape),
            jnp.zeros((H,) + state.data.qvel.shape),
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
            nstate = jax.vmap(mjx_env.step)(state, action)
            alive = ~done
            reward = jnp.where(alive, nstate.reward, 0.0)
            obs_b = obs_b.at[t].set(jnp.where(alive[:, None], state.obs, 0.0))
            act_b = act_b.at[t].set(jnp.where(alive[:, None], action, 0.0))
            rew_b = rew_b.at[t].set(reward)
            qpos_b = qpos_b.at[t].set(jnp.where(alive[:, None], state.data.qpos, 0.0))
            qvel_b = qvel_b.at[t].set(jnp.where(alive[:, None], state.data.qvel, 0.0))
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
