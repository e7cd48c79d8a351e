"""Train a SAC behaviour policy in MJX, pmap-free, for making D4RL-style datasets.

    python -m minsubdt_jax.behavior.train --env hopper --steps 300000        # runs/behavior/hopper
    python -m minsubdt_jax.behavior.train --env hopper --steps 400000 --resume   # continue, or go further

D4RL made its datasets with SAC; on 2 CPU cores brax's PPO stalled on hopper-mjx while SAC with one gradient
update per transition learned in minutes (``../shared/NOTES.md``), so this is SAC: ``num_envs`` MJX
environments under ``vmap``, and each jitted chunk is one ``lax.scan`` over (step every env, store the
transitions, ``num_envs * updates_per_transition`` gradient updates). The replay buffer lives in the
train state, so the whole chunk is one XLA program.

Every ``eval_every`` env steps the stochastic policy is evaluated on ``eval_episodes`` 1000-step episodes
and its actor saved as ``snapshots/step_XXXXXXXX.npz`` (listed with its return in ``snapshots.jsonl``):
the snapshots are what datasets are recorded from. A checkpoint (orbax: networks, optimisers, replay
buffer, counters) follows each evaluation; ``--resume`` restarts from it with freshly reset episodes.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import os
import sys
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
import orbax.checkpoint as ocp
from flax import struct

from ..caches import enable_compilation_cache
from ..envs import MjxEnv, env_spec, make_rollout
from ..loop import chunk_loop
from ..rundir import check_run_dir, checkpoint_manager, exit_code, truncate_metrics, write_atomic
from .config import SACConfig, parse_args, train_command, validate
from .losses import Transition, actor_loss, alpha_loss, critic_loss
from .networks import Actor, DoubleCritic, policy_step, sample_tanh_gaussian
from .snapshots import save_snapshot
from .tradeoffs import objectives

RESUMABLE_CHANGES = ("steps", "out")


@struct.dataclass
class SACState:
    actor_params: Any
    critic_params: Any
    target_critic_params: Any
    log_alpha: jax.Array
    actor_opt: Any
    critic_opt: Any
    alpha_opt: Any
    buffer: Transition  # [capacity, ...]
    buffer_pos: jax.Array  # next row to write
    buffer_len: jax.Array  # rows filled
    env_steps: jax.Array
    episode_return: jax.Array  # [num_envs] running return of the current training episodes
    episode_len: jax.Array  # [num_envs]
    wall_seconds: jax.Array  # training wall time summed over resumptions
    rng: jax.Array


_CHUNKS: dict = {}  # compiled chunks, shared by SAC instances of equal settings (e.g. a run and its resumption)
_RESETS: dict = {}  # the envs' jitted reset by (env, num_envs), likewise: tracing MJX's reset takes seconds


class SAC:
    """Networks, optimisers and the jitted chunk for one :class:`SACConfig`."""

    def __init__(self, cfg: SACConfig):
        self.cfg = validate(cfg)
        self.spec = env_spec(cfg.env)
        self.env = MjxEnv(env_spec(cfg.env).name)  # the SAC loop is one jitted scan: MJX
        self.actor = Actor(self.spec.act_dim, (cfg.hidden, cfg.hidden))
        self.critic = DoubleCritic((cfg.hidden, cfg.hidden))
        self.tx = optax.adam(cfg.learning_rate)
        self.target_entropy = -float(self.spec.act_dim)
        # the training reward is the env's plus reshape * |a|^2: the env's control cost swapped for lambda's
        self.reshape = 0.0 if cfg.energy_weight is None else self.spec.dynamics["brax"].ctrl_cost - cfg.energy_weight

    def init(self, rng) -> tuple[SACState, Any]:
        """A fresh state (empty buffer) and freshly reset environments."""
        cfg, spec = self.cfg, self.spec
        k_actor, k_critic, k_env, rng = jax.random.split(rng, 4)
        obs, act = jnp.zeros((1, spec.obs_dim)), jnp.zeros((1, spec.act_dim))
        actor_params = self.actor.init(k_actor, obs)
        critic_params = self.critic.init(k_critic, obs, act)
        log_alpha = jnp.zeros(())
        C = cfg.capacity
        buffer = Transition(obs=jnp.zeros((C, spec.obs_dim)), action=jnp.zeros((C, spec.act_dim)),
                            reward=jnp.zeros(C), discount=jnp.zeros(C), next_obs=jnp.zeros((C, spec.obs_dim)))
        z = jnp.zeros((), jnp.int32)
        state = SACState(actor_params=actor_params, critic_params=critic_params, target_critic_params=critic_params,
                         log_alpha=log_alpha, actor_opt=self.tx.init(actor_params),
                         critic_opt=self.tx.init(critic_params), alpha_opt=self.tx.init(log_alpha), buffer=buffer,
                         buffer_pos=z, buffer_len=z, env_steps=z, episode_return=jnp.zeros(cfg.num_envs),
                         episode_len=jnp.zeros(cfg.num_envs, jnp.int32), wall_seconds=jnp.zeros(()), rng=rng)
        return _distinct(state), self.reset_envs(k_env)

    def reset_envs(self, rng):
        key = (self.spec.name, self.cfg.num_envs)
        if key not in _RESETS:
            _RESETS[key] = jax.jit(jax.vmap(self.env.reset))
        return _distinct(_RESETS[key](jax.random.split(rng, self.cfg.num_envs)))

    def update(self, state: SACState, rng) -> tuple[SACState, dict]:
        """One gradient update of critics, actor and temperature on a uniform batch from the buffer."""
        cfg = self.cfg
        k_idx, k_critic, k_actor = jax.random.split(rng, 3)
        idx = jax.random.randint(k_idx, (cfg.batch_size,), 0, state.buffer_len)
        batch = jax.tree.map(lambda x: x[idx], state.buffer)
        c_loss, c_grad = jax.value_and_grad(critic_loss)(
            state.critic_params, state.target_critic_params, state.actor_params, state.log_alpha, batch, k_critic,
            actor=self.actor, critic=self.critic, gamma=cfg.gamma)
        upd, critic_opt = self.tx.update(c_grad, state.critic_opt)
        critic_params = optax.apply_updates(state.critic_params, upd)
        (a_loss, logp), a_grad = jax.value_and_grad(actor_loss, has_aux=True)(
            state.actor_params, critic_params, state.log_alpha, batch, k_actor, actor=self.actor, critic=self.critic)
        upd, actor_opt = self.tx.update(a_grad, state.actor_opt)
        actor_params = optax.apply_updates(state.actor_params, upd)
        al_grad = jax.grad(alpha_loss)(state.log_alpha, logp, self.target_entropy)
        upd, alpha_opt = self.tx.update(al_grad, state.alpha_opt)
        log_alpha = optax.apply_updates(state.log_alpha, upd)
        target = optax.incremental_update(critic_params, state.target_critic_params, cfg.tau)
        state = state.replace(actor_params=actor_params, critic_params=critic_params, target_critic_params=target,
                              log_alpha=log_alpha, actor_opt=actor_opt, critic_opt=critic_opt, alpha_opt=alpha_opt)
        return state, {"critic_loss": c_loss, "actor_loss": a_loss, "alpha": jnp.exp(log_alpha),
                       "entropy": -jnp.mean(logp)}

    def env_step(self, state: SACState, env_state, explore):
        """Step every env once (uniform actions if ``explore``, a traced bool, else the stochastic actor), store
        the transitions, reset ended episodes. Returns ``(state, env_state, (completed return sum, count))``."""
        cfg, n = self.cfg, self.cfg.num_envs
        rng, k_act, k_reset = jax.random.split(state.rng, 3)
        uniform = jax.random.uniform(k_act, (n, self.spec.act_dim), minval=-1.0, maxval=1.0)
        sampled, _ = sample_tanh_gaussian(*self.actor.apply(state.actor_params, env_state.obs), k_act)
        action = jnp.where(explore, uniform, sampled)
        nstate = jax.vmap(self.env.step)(env_state, action)
        reward = nstate.reward + self.reshape * jnp.sum(jnp.square(action), -1)
        terminal = nstate.done > 0
        ep_len = state.episode_len + 1
        ep_ret = state.episode_return + reward
        ended = terminal | (ep_len >= cfg.episode_length)
        rows = Transition(obs=env_state.obs, action=action, reward=reward,
                          discount=1.0 - terminal.astype(jnp.float32), next_obs=nstate.obs)
        buffer = jax.tree.map(lambda b, r: jax.lax.dynamic_update_slice_in_dim(b, r, state.buffer_pos, 0),
                              state.buffer, rows)
        fresh = jax.lax.cond(jnp.any(ended), lambda: jax.vmap(self.env.reset)(jax.random.split(k_reset, n)),
                             lambda: nstate)
        env_state = jax.tree.map(lambda f, s: jnp.where(ended.reshape(ended.shape + (1,) * (s.ndim - 1)), f, s),
                                 fresh, nstate)
        state = state.replace(buffer=buffer, buffer_pos=(state.buffer_pos + n) % cfg.capacity,
                              buffer_len=jnp.minimum(state.buffer_len + n, cfg.capacity),
                              env_steps=state.env_steps + n, episode_return=jnp.where(ended, 0.0, ep_ret),
                              episode_len=jnp.where(ended, 0, ep_len), rng=rng)
        return state, env_state, (jnp.sum(jnp.where(ended, ep_ret, 0.0)), jnp.sum(ended))

    def chunk(self):
        """Jitted ``chunk(state, env_state, explore) -> (state, env_state, metrics)`` over ``chunk_steps`` env
        steps; no gradient updates while ``explore`` (the random-action warm-up; a traced flag, so both phases
        run the one compiled program)."""
        key = dataclasses.replace(self.cfg, steps=1, out=None)  # what the program depends on
        if key in _CHUNKS:
            return _CHUNKS[key]
        cfg = self.cfg
        n_updates = cfg.num_envs * cfg.updates_per_transition

        def learn(state):
            rng, k = jax.random.split(state.rng)
            state, info = jax.lax.scan(self.update, state.replace(rng=rng), jax.random.split(k, n_updates))
            return state, jax.tree.map(jnp.mean, info)

        def iteration(carry, _, explore):
            state, env_state = carry
            state, env_state, (ret_sum, count) = self.env_step(state, env_state, explore)
            info_shape = jax.eval_shape(learn, state)[1]
            state, info = jax.lax.cond(explore, lambda s: (s, jax.tree.map(jnp.zeros_like, info_shape)), learn, state)
            return (state, env_state), (ret_sum, count, info)

        def chunk(state, env_state, explore):
            (state, new_env_state), (ret_sum, count, info) = jax.lax.scan(
                functools.partial(iteration, explore=explore), (state, env_state), None,
                length=cfg.chunk_steps // cfg.num_envs)
            metrics = jax.tree.map(jnp.mean, info)
            metrics["train_return_sum"], metrics["train_episodes"] = jnp.sum(ret_sum), jnp.sum(count)
            # brax's step makes some leaves weak-typed (done, a metric): give back the input's types, or the next
            # call would compile this program a second time
            return state, jax.tree.map(lambda n, o: jax.lax.convert_element_type(n, o.dtype), new_env_state,
                                       env_state), metrics

        _CHUNKS[key] = jax.jit(chunk, donate_argnums=(0, 1))
        return _CHUNKS[key]

    def evaluate(self, actor_params, rng) -> dict:
        """The stochastic policy over ``eval_episodes`` episodes of ``episode_length`` steps: ``return`` (the env's
        reward) ``[n]``, and with ``energy_weight`` the training reward's return ``objective`` and the
        :func:`~minsubdt_jax.behavior.tradeoffs.objectives`."""
        run = make_rollout(self.cfg.env, policy_step, self.cfg.eval_episodes, self.cfg.episode_length)
        ro = jax.device_get(run(actor_params, (), rng))
        out = {"return": np.asarray(ro.rewards).sum(1)}
        if self.cfg.energy_weight is not None:
            speed, energy = objectives(self.spec.name, ro)
            out.update(objective=out["return"] + self.reshape * energy, speed=speed, energy=energy)
        return out


def _distinct(tree):
    """Copy every leaf, so no two leaves share a buffer (the chunk donates its inputs)."""
    return jax.tree.map(jnp.copy, tree)


def train(cfg: SACConfig, resume: bool = False, verbose: bool = True) -> list[dict]:
    """Train (or continue) in ``cfg.run_dir()``; returns the snapshot records (``snapshots.jsonl``)."""
    sac = SAC(cfg)
    out = cfg.run_dir()
    ckpt_dir = os.path.abspath(os.path.join(out, "checkpoints"))
    check_run_dir(dataclasses.asdict(cfg), out, ckpt_dir, resume, RESUMABLE_CHANGES)
    os.makedirs(os.path.join(out, "snapshots"), exist_ok=True)
    write_atomic(os.path.join(out, "config.json"), json.dumps(dataclasses.asdict(cfg), indent=2, sort_keys=True))
    state, env_state = sac.init(jax.random.PRNGKey(cfg.seed))
    mngr = checkpoint_manager(ckpt_dir, keep=1)
    if resume:
        # orbax gives committed arrays, fresh ones are not, and that is part of a program's compile key: through the
        # host, so the resumed run reuses the compiled programs (persistent compilation cache) of the first one
        restored = mngr.restore(mngr.latest_step(), args=ocp.args.StandardRestore(state))
        state = jax.tree.map(lambda x: jnp.asarray(np.asarray(x)), restored)
        env_state = sac.reset_envs(jax.random.fold_in(state.rng, 1))
        if verbose:
            print(f"resumed from env step {int(state.env_steps)}", flush=True)
    start = int(state.env_steps)
    metrics_path, snaps_path = os.path.join(out, "metrics.jsonl"), os.path.join(out, "snapshots.jsonl")
    truncate_metrics(metrics_path, start)
    truncate_metrics(snaps_path, start)
    last_return = float("nan")

    def snapshot_due(step):  # an evaluated snapshot, and the checkpoint beside it (the state holds the buffer)
        return step % cfg.eval_every == 0 or step >= cfg.steps

    def chunk(step, bar):
        nonlocal state, env_state, last_return
        t0 = time.time()
        explore = step < cfg.min_replay
        state, env_state, m = sac.chunk()(state, env_state, jnp.asarray(explore))
        m = {k: float(v) for k, v in jax.device_get(m).items()
             if not explore or k.startswith("train_")}  # no update metrics in the warm-up: there were no updates
        state = state.replace(wall_seconds=state.wall_seconds + (time.time() - t0))
        step = int(state.env_steps)
        if m["train_episodes"]:
            last_return = m["train_return_sum"] / m["train_episodes"]
        row = {"step": step, "wall_seconds": float(state.wall_seconds), "train_return": last_return,
               **{k: v for k, v in m.items() if k not in ("train_return_sum",)}}
        with open(metrics_path, "a") as f:
            f.write(json.dumps(row) + "\n")
        if snapshot_due(step):
            _snapshot(sac, state, step, out, snaps_path, bar if verbose else None)
        bar.set_postfix(ret=f"{last_return:.0f}", alpha=f"{m.get('alpha', 1.0):.3f}")
        bar.update(cfg.chunk_steps)
        return step

    def save(step, stopping):  # at each snapshot, and on Ctrl-C
        if snapshot_due(step) or stopping:
            mngr.save(step, args=ocp.args.StandardSave(state))

    chunk_loop(start, cfg.steps, chunk, save, resume=train_command(dataclasses.asdict(cfg)) + " --resume", verbose=verbose, unit="env-step")
    with open(snaps_path) as f:
        return [json.loads(ln) for ln in f if ln.strip()]


def _snapshot(sac, state, step: int, out: str, snaps_path: str, bar) -> None:
    """Evaluate the actor at ``step``, save it as a snapshot and append its record to ``snapshots.jsonl``."""
    te = time.time()
    ev = sac.evaluate(state.actor_params, jax.random.fold_in(jax.random.PRNGKey(sac.cfg.seed + 1), step))
    returns, name = ev["return"], f"step_{step:08d}.npz"
    save_snapshot(os.path.join(out, "snapshots", name), state.actor_params, env=sac.spec.name, step=step,
                  return_mean=returns.mean())
    rec = {"step": step, "snapshot": name, "return_mean": float(returns.mean()), "return_std": float(returns.std()),
           "episodes": len(returns), "wall_seconds": float(state.wall_seconds), "eval_seconds": time.time() - te,
           **{f"{k}_mean": float(np.mean(v)) for k, v in ev.items() if k != "return"}}
    with open(snaps_path, "a") as f:
        f.write(json.dumps(rec) + "\n")
    if bar is not None:
        bar.write(f"step {step}: eval return {rec['return_mean']:.1f} ± {rec['return_std']:.1f} "
                  f"({rec['episodes']} episodes), wall {rec['wall_seconds']:.0f} s")


def main(argv=None) -> int:
    enable_compilation_cache()
    return exit_code(lambda: train(*parse_args(argv)))


if __name__ == "__main__":
    sys.exit(main())
