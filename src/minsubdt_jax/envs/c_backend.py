"""C MuJoCo physics: batched rollouts on ``mujoco.batch.Batch`` (mujoco >= 4.0), the fast path on a CPU.

A ``Batch`` holds one simulation per episode on a thread pool; it is bit-identical to a loop of ``mj_step`` at any
thread count and keeps each simulation's solver warm start, so a rollout here is the continuous simulation that
MJX runs (in float64; MJX in float64 equals it to 1e-14). Each decision step: the rules
(:mod:`minsubdt_jax.envs.rules`, in numpy float64) give the observations, one jitted call of the policy gives every
episode's action (``vmap`` over the seed axis), ``ctrl`` rows are written and the live episodes step
``frame_skip`` substeps. Resets are drawn by the same JAX function as MJX's, from the same keys, and the policy
gets the same keys, so the two backends roll out the same episodes up to float rounding (tested).

``mujoco.rollout`` is not used: it zeroes the warm start on every call and returns no derived fields (``xpos``).
"""

from __future__ import annotations

import functools
import os

import jax
import jax.numpy as jnp
import numpy as np

from .rules import TORSO, env_rules, forward_position, mj_model, observe, reset_state, step_outcome
from .spec import Policy, Rollout, env_spec


def default_threads() -> int:
    """The machine's cores (what ``--physics-threads 0`` means)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


class Sims:
    """``nsim`` C simulations of ``env`` in ``dynamics`` with live views of their state rows: ``qpos``, ``qvel``,
    ``ctrl``, ``warm`` (the solver's warm start) and ``xpos`` (derived, refreshed by every call)."""

    def __init__(self, env: str, dynamics: str, nsim: int, threads: int = 0):
        import mujoco.batch

        self.rules = env_rules(env, dynamics)
        self.model = mj_model(env, dynamics)
        self.batch = mujoco.batch.Batch(self.model, nsim, nthread=threads or default_threads())
        b = self.batch
        self.qpos, self.qvel, self.ctrl, self.warm = b.bind("qpos"), b.bind("qvel"), b.bind("ctrl"), b.bind(
            "qacc_warmstart")
        self.xpos = b.bind("xpos")

    def set_state(self, qpos, qvel, ids=None) -> None:
        """Put simulations ``ids`` (all: ``None``) in the state ``qpos [n, nq]``, ``qvel [n, nv]``, warm start 0,
        controls 0, and compute their derived fields (``mj_forward``), as gym's ``set_state`` after a reset."""
        sel = slice(None) if ids is None else ids
        self.batch.reset(ids, stage=0)  # mjSTAGE_NONE: clear time, act, warm start; the state is written next
        self.qpos[sel] = qpos
        self.qvel[sel] = qvel
        self.warm[sel] = 0.0
        self.ctrl[sel] = 0.0
        self.batch.forward(ids)

    def step(self, action, ids=None) -> None:
        """One decision step (``frame_skip`` substeps) of simulations ``ids`` with controls ``action [n, act]``."""
        self.ctrl[slice(None) if ids is None else ids] = action
        self.batch.step(ids, nstep=self.rules.frame_skip)

    def torso(self) -> np.ndarray:
        return np.array(self.xpos[:, TORSO])


@functools.lru_cache(maxsize=8)
def _sims(env: str, dynamics: str, nsim: int, threads: int) -> Sims:
    return Sims(env, dynamics, nsim, threads)


@functools.lru_cache(maxsize=32)
def make_c_seed_rollout(env: str, policy: Policy, num_episodes: int, horizon: int, dynamics: str = "brax",
                        threads: int = 0):
    """``run(inputs [S, ...], carry, rngs [S]) -> Rollout [S, n, ...]`` (numpy): S models of ``policy``, each on
    ``num_episodes`` episodes seeded by its key, as ``jit(vmap(make_mjx_rollout(...)))`` does in MJX. ``carry`` is
    the policy's initial carry for ``n`` episodes (the same for every model)."""
    rules, spec = env_rules(env, dynamics), env_spec(env)
    n, H = int(num_episodes), int(horizon)
    qpos0 = np.asarray(mj_model(env, dynamics).qpos0, np.float32)

    def first(rng):  # as the MJX rollout: its key, then the episodes' reset keys
        rng, reset_rng = jax.random.split(rng)
        return rng, jax.vmap(lambda k: reset_state(rules, qpos0, k))(jax.random.split(reset_rng, n))

    def decide(params, carry, obs, prev_r, t, rng):
        rng, key = jax.random.split(rng)
        carry, action = policy(params, carry, obs, prev_r, t, key)
        return carry, jnp.clip(action, -1.0, 1.0), rng

    first_s = jax.jit(jax.vmap(first))
    decide_s = jax.jit(jax.vmap(decide, in_axes=(0, 0, 0, 0, None, 0)))

    def run(inputs, carry, rngs):
        S = int(np.shape(rngs)[0])
        N = S * n
        sims = _sims(spec.name, dynamics, N, int(threads))
        rng, (q0, v0) = first_s(rngs)
        sims.set_state(np.asarray(q0, np.float64).reshape(N, -1), np.asarray(v0, np.float64).reshape(N, -1))
        carry = jax.tree.map(lambda x: jnp.broadcast_to(x, (S,) + jnp.shape(x)), carry)
        obs_b = np.zeros((N, H, spec.obs_dim), np.float32)
        act_b = np.zeros((N, H, spec.act_dim), np.float32)
        rew_b = np.zeros((N, H), np.float32)
        qpos_b = np.zeros((N, H, sims.qpos.shape[1]), np.float32)
        qvel_b = np.zeros((N, H, sims.qvel.shape[1]), np.float32)
        done = np.zeros(N, bool)  # only terminations end an episode before the horizon: done is `terminated`
        length, prev_r = np.zeros(N, np.int32), np.zeros(N, np.float32)
        qpos, qvel, torso = np.array(sims.qpos), np.array(sims.qvel), sims.torso()
        for t in range(H):
            alive = ~done
            ids = np.flatnonzero(alive).astype(np.int32)
            obs = observe(rules, qpos, qvel, torso, np).astype(np.float32)
            carry, action, rng = decide_s(inputs, carry, obs.reshape(S, n, -1), prev_r.reshape(S, n), t, rng)
            action = np.asarray(action, np.float64).reshape(N, -1)
            sims.step(action[ids], ids)
            x_before = forward_position(rules, qpos, torso)
            qpos_b[ids, t], qvel_b[ids, t] = qpos[ids], qvel[ids]
            qpos, qvel, torso = np.array(sims.qpos), np.array(sims.qvel), sims.torso()  # the next step's state
            reward, ended = step_outcome(rules, x_before, qpos, qvel, torso, action, np)
            reward = np.where(alive, reward, 0.0).astype(np.float32)
            obs_b[ids, t], act_b[ids, t], rew_b[:, t] = obs[ids], action[ids], reward
            done |= alive & ended
            length += alive
            prev_r = reward
            if done.all():
                break
        shape = lambda x: x.reshape((S, n) + x.shape[1:])  # noqa: E731
        return Rollout(observations=shape(obs_b), actions=shape(act_b), rewards=shape(rew_b), lengths=shape(length),
                       terminated=shape(done), qpos=shape(qpos_b), qvel=shape(qvel_b))

    return run


def make_c_rollout(env: str, policy: Policy, num_episodes: int, horizon: int, dynamics: str = "brax",
                   threads: int = 0):
    """``run(policy_params, policy_carry, rng) -> Rollout`` for one model: :func:`make_c_seed_rollout` with S = 1."""
    seeds = make_c_seed_rollout(env, policy, num_episodes, horizon, dynamics, threads)

    def run(policy_params, policy_carry, rng):
        ro = seeds(jax.tree.map(lambda x: jnp.asarray(x)[None], policy_params), policy_carry, jnp.asarray(rng)[None])
        return jax.tree.map(lambda x: x[0], ro)

    return run
