"""The AWR agent, offline, as d4rl_evaluations ``awr/`` (its class defaults, which its D4RL runs used): value and
policy MLPs of 128 x 64, a Gaussian policy with fixed std 0.2, SGD with momentum 0.9 (value 1e-2, policy 5e-5),
TD(lambda = 0.95) value targets, temperature 1.0 on standardised advantages, weights clipped at 20, an action-bound
loss of weight 10, 256 per batch.

AWR is iterative: each iteration computes the lambda-returns of the whole dataset with the current value, fits the
value to them (200 steps), computes the advantages and fits the policy (1000 steps). Here one iteration is one
train chunk (``--chunk-steps``, the sixth part value steps, the rest policy steps, the reference's 1 : 5;
``--chunk-steps 1200`` is the reference's iteration), so it runs in the same jitted, checkpointed, vmapped loop.

Choices: the value net predicts ``V (1 - gamma)`` (the reference normalises its values by ``1 / (1 - gamma)``);
a time-out's last step bootstraps from its own state's value (the data hold no final state). D4RL's AWR runs kept
the dataset in a 50,000-transition replay buffer (``ReplayBuffer(50000)`` in ``run_script.py``), so most of a 1M
dataset was dropped; here every transition is used. Deterministic evaluation: the policy's mean, clipped."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, ClassVar

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax

from ...networks import MLP, f32
from ...data import draw_episodes
from ..actor_critic import TransitionAgent
from ..base import PolicyInputs, TrainState, ema_update
from .losses import actor_loss, advantage_weights, lambda_returns


class Net(nn.Module):
    """``states -> [..., out]``: the reference's 128 x 64 ReLU MLP and a linear head."""

    out: int
    hidden: tuple = (128, 64)
    dtype: Any = None  # the matmuls' (--precision bf16); parameters and output float32

    @nn.compact
    def __call__(self, states):
        return f32(nn.Dense(self.out, dtype=self.dtype)(MLP(self.hidden, self.dtype)(states)))


@dataclass(frozen=True)
class AWRAgent(TransitionAgent):
    """AWR on :class:`~minsubdt_jax.agents.actor_critic.TransitionAgent`: no critic, no targets; its chunk is one
    iteration (:meth:`make_chunk`), which cannot be cut into shorter ones."""

    whole_chunks: ClassVar[bool] = True
    lam: float = 0.95
    temperature: float = 1.0
    action_std: float = 0.2
    value_every: int = 6  # one value step in every 6 of an iteration, first (the reference's 200 of 1200)

    @property
    def networks(self):
        return Net(self.act_dim, self.hidden, self.dtype), Net(1, self.hidden, self.dtype)

    def init_params(self, key):
        actor, value = self.networks
        ka, kv = jax.random.split(key)
        s = jnp.zeros((1, self.obs_dim))
        return {"actor": actor.init(ka, s), "value": value.init(kv, s)}

    @property
    def optimizers(self) -> dict:
        return {"actor": optax.sgd(self.actor_lr, momentum=0.9), "value": optax.sgd(self.critic_lr, momentum=0.9)}

    def value(self, params, states):
        return self.networks[1].apply(params, states)[..., 0] / (1.0 - self.discount)

    def make_chunk(self, tx, batch_size: int, n_steps: int, mesh=None, *, seed_axis: bool = False, data_axis=None,
                   ema_decay: float = 0.0):
        """Jitted ``chunk(state, data) -> (state, (losses [n_steps(, S)], parts))``: one AWR iteration (per seed, on
        a leading seed axis with ``seed_axis``) of its own ``batch_size`` transitions per step. One device: the
        batch is not split over a mesh."""
        opt = self.optimizers
        n_value = n_steps // self.value_every

        def iteration(state: TrainState, data):
            valid = jnp.arange(data.states.shape[1])[None, :] < data.lengths[:, None]

            def all_values(params):  # V of every stored state, an episode at a time
                return jax.lax.map(lambda s: self.value(params, s), data.states) * valid

            returns = lambda_returns(data.rewards, all_values(state.params["value"]), data.lengths, data.last_done,
                                     self.discount, self.lam)

            def sample(rng):
                k1, k2 = jax.random.split(rng)
                traj = draw_episodes(k1, data.weights, self.batch_size)
                t = jnp.minimum(jnp.floor(jax.random.uniform(k2, (self.batch_size,)) * data.lengths[traj]),
                                data.lengths[traj] - 1).astype(jnp.int32)
                return traj, t

            def update(state, name, loss_fn):
                rng, k = jax.random.split(state.rng)
                traj, t = sample(k)
                loss, g = jax.value_and_grad(loss_fn)(state.params[name], traj, t)
                upd, o = opt[name].update(g, state.opt_state[name], state.params[name])
                params = dict(state.params, **{name: optax.apply_updates(state.params[name], upd)})
                ema = ema_update(state.ema_params, params, state.step, ema_decay)
                return TrainState(step=state.step + 1, params=params, opt_state=dict(state.opt_state, **{name: o}),
                                  rng=rng, ema_params=ema), loss

            def value_loss(p, traj, t):  # in the normalised units of the net's output
                return (((self.value(p, data.states[traj, t]) - returns[traj, t]) * (1.0 - self.discount)) ** 2).mean()

            state, v_losses = jax.lax.scan(lambda s, _: update(s, "value", value_loss), state, None, length=n_value)
            weights = advantage_weights(returns - all_values(state.params["value"]), valid, self.temperature)

            def policy_loss(p, traj, t):
                mean = self.networks[0].apply(p, data.states[traj, t])
                return actor_loss(mean, data.actions[traj, t], weights[traj, t], self.action_std)

            state, a_losses = jax.lax.scan(lambda s, _: update(s, "actor", policy_loss), state, None,
                                           length=n_steps - n_value)
            losses = jnp.concatenate([v_losses, a_losses])
            return state, (losses, {"value": v_losses.mean() if n_value else jnp.zeros(()), "actor": a_losses.mean()})

        def chunk(state, data):
            if not seed_axis:
                return iteration(state, data)
            state, (losses, parts) = jax.vmap(iteration, in_axes=(0, data_axis))(state, data)
            return state, (losses.T, parts)  # [n_steps, S], as the scanned chunks give them

        return jax.jit(chunk, donate_argnums=0)

    @property
    def policy(self):
        return awr_policy(self.networks[0])


@functools.lru_cache(maxsize=None)
def awr_policy(actor: Net):
    def policy(p: PolicyInputs, carry, obs, prev_reward, t, rng):
        return carry, jnp.clip(actor.apply(p.params["actor"], p.normalise(obs)), -1.0, 1.0)

    return policy


def make_awr_agent(cfg, obs_dim: int, act_dim: int, max_timestep: int) -> AWRAgent:
    return AWRAgent(obs_dim=obs_dim, act_dim=act_dim, hidden=(cfg.ac_hidden or 128, 64) if cfg.ac_layers in (None, 2)
                    else (cfg.ac_hidden or 128,) * cfg.ac_layers, discount=cfg.discount,
                    batch_size=cfg.critic_batch_size, actor_lr=cfg.actor_lr or 5e-5, critic_lr=cfg.critic_lr or 1e-2,
                    precision=cfg.precision)
