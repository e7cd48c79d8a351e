"""The shared base of the critic agents (IQL, TD3+BC, CQL): transitions instead of windows, one optimiser per
network, Polyak-averaged target networks, delayed updates, and a deterministic rollout policy on normalised states.

A critic agent is a frozen record (``agents/<name>/agent.py``) with, besides :class:`~minsubdt_jax.agents.base.Agent`'s
``init_params``, ``policy`` and ``initial_carry``:

* ``params``: a dict of networks, e.g. ``{"actor", "critic", "target_critic", "value"}``;
* ``optimizers``: ``{name: optax transformation}`` for the networks that train (the others are targets);
* ``losses(params, batch: Transitions, rng, step) -> {name: loss}`` (the base's ``loss`` sums them), each with
  ``stop_gradient`` on the networks it must not move, so that **one** backward pass gives every network the
  gradient of its own loss (unifloral's single update; cheaper than one pass per loss, as JaxCQL's);
* ``active(step) -> {name: bool}``: networks updated only on some steps (TD3+BC's delayed actor), else all;
* ``constrain(params)``: a projection after each update (BEAR clamps its dual), else the identity;
* ``targets(step) -> [(target, source, on)]``: the Polyak updates ``target <- tau source + (1 - tau) target`` made
  after the gradient step (``on``: a traced bool, or None for every step).

:func:`make_ac_step` is the train step the shared run loop scans and vmaps over seeds, as it does the DT's.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import ClassVar

import jax
import jax.numpy as jnp
import optax

from ..data import SamplerData, sample_transitions
from ..parallel import shard_batch
from .base import PolicyInputs, StepAgent, TrainState, ema_update


def polyak(target, online, tau: float):
    """``tau * online + (1 - tau) * target``, leaf by leaf."""
    return jax.tree.map(lambda t, o: tau * o + (1.0 - tau) * t, target, online)


def tree_where(on, new, old):
    """``new`` where the traced bool ``on`` holds, else ``old`` (leaf by leaf)."""
    return jax.tree.map(lambda a, b: jnp.where(on, a, b), new, old)


def per_network_optimizer(optimizers: dict) -> optax.GradientTransformation:
    """The state of one optimiser per network, ``{name: state}``, for :func:`~minsubdt_jax.agents.base.init_state`;
    the updates are made by :func:`make_ac_step`, network by network."""

    def update(updates, state, params=None):
        raise TypeError("a critic agent's networks are updated one by one: use agents.actor_critic.make_ac_step")

    return optax.GradientTransformation(lambda params: {k: tx.init(params[k]) for k, tx in optimizers.items()},
                                        update)


def make_ac_step(agent, batch_size: int, mesh=None, ema_decay: float = 0.0):
    """Pure ``step(state, data) -> (state, (loss, parts))`` of a critic agent (``parts``: each loss, by name, as
    ``metrics.jsonl`` logs them per chunk): sample transitions
    (:func:`~minsubdt_jax.data.sample_transitions`), one backward pass through the summed losses, each trained
    network's own optimiser (skipped, state and all, where ``agent.active`` says so: zeroed gradients would still
    move Adam's moments), then the Polyak updates of the targets and the parameters' moving average."""
    optimizers = agent.optimizers

    def step(state: TrainState, data: SamplerData):
        rng, k_batch, k_loss = jax.random.split(state.rng, 3)
        batch = shard_batch(sample_transitions(k_batch, data, batch_size), mesh)
        (loss, parts), grads = jax.value_and_grad(agent.loss, has_aux=True)(state.params, batch, k_loss, state.step)
        active = agent.active(state.step)
        params, opt_state = dict(state.params), dict(state.opt_state)
        for name, tx in optimizers.items():
            updates, new_opt = tx.update(grads[name], state.opt_state[name], state.params[name])
            new = optax.apply_updates(state.params[name], updates)
            on = active.get(name)
            params[name] = new if on is None else tree_where(on, new, state.params[name])
            opt_state[name] = new_opt if on is None else tree_where(on, new_opt, state.opt_state[name])
        params = agent.constrain(params)
        for target, source, on in agent.targets(state.step):
            moved = polyak(params[target], params[source], agent.tau)
            params[target] = moved if on is None else tree_where(on, moved, params[target])
        ema = ema_update(state.ema_params, params, state.step, ema_decay)
        new = TrainState(step=state.step + 1, params=params, opt_state=opt_state, rng=rng, ema_params=ema)
        return new, (loss, parts)

    return step


@functools.lru_cache(maxsize=None)
def deterministic_policy(actor, kind: str):
    """The rollout policy of an ``actor`` module (cached per module, so the compiled rollout is reused) on
    normalised states: ``kind`` ``"action"`` (the actor's output), ``"mean"`` (the Gaussian's mean, IQL) or
    ``"tanh_mean"`` (``tanh`` of the pre-squash mean, SAC/CQL): every reference evaluates deterministically."""

    def policy(p: PolicyInputs, carry, obs, prev_reward, t, rng):
        out = actor.apply(p.params["actor"], p.normalise(obs))
        action = out if kind == "action" else out[0] if kind == "mean" else jnp.tanh(out[0])
        return carry, action

    return policy


@dataclass(frozen=True)
class TransitionAgent:
    """Fields every agent that trains on transitions has (from :class:`~minsubdt_jax.config.Config`): data shapes,
    network width and depth, the discount, transitions per step, the actor's and critics' (or value net's) rates,
    and one optimiser per network (``optimizers``). AWR's base; the critic agents' through
    :class:`CriticAgentBase`."""

    obs_dim: int
    act_dim: int
    hidden: tuple
    discount: float
    batch_size: int
    actor_lr: float
    critic_lr: float
    precision: str = "f32"  # f32 | tf32 (TF32 matmuls where the device has them) | bf16 (bfloat16 matmuls)
    context_len: ClassVar[int] = 1  # the shared interface's window; these agents sample transitions

    @property
    def dtype(self):
        """The networks' matmul dtype: bfloat16 at ``--precision bf16``, else float32 (None)."""
        return jnp.bfloat16 if self.precision == "bf16" else None

    def initial_carry(self, n: int):
        return ()

    def optimizer(self, cfg=None) -> optax.GradientTransformation:
        return per_network_optimizer(self.optimizers)


@dataclass(frozen=True)
class CriticAgentBase(TransitionAgent, StepAgent):
    """A critic agent: :class:`TransitionAgent` with Polyak-averaged targets (rate ``tau``) and the shared chunk
    scanning its own step, :func:`make_ac_step`."""

    tau: float = 0.005

    def make_step(self, tx, batch_size: int, mesh=None, ema_decay: float = 0.0):
        return make_ac_step(self, batch_size, mesh, ema_decay)

    def loss(self, params, batch, rng, step=None):
        """``(total, parts)``: the agent's ``losses(params, batch, rng, step)`` (a dict) and their sum."""
        if self.precision == "tf32":  # read when the step is traced
            with jax.default_matmul_precision("tensorfloat32"):
                parts = self.losses(params, batch, rng, step)
        else:
            parts = self.losses(params, batch, rng, step)
        return sum(parts.values()), parts

    def targets(self, step):
        """The Polyak pairs: by default the critics' target, every step."""
        return [("target_critic", "critic", None)]

    def active(self, step) -> dict:
        return {}

    def constrain(self, params):
        """The parameters after an update, projected where the agent bounds them (BEAR's log alpha)."""
        return params

    def _init(self, key, actor, critic, extra=()):
        """``{"actor", "critic", "target_critic"}`` (the target a copy of the critic) and ``extra``'s
        ``(name, module, *inputs)``, each from its own key."""
        keys = jax.random.split(key, 2 + len(extra))
        s, a = jnp.zeros((1, self.obs_dim)), jnp.zeros((1, self.act_dim))
        params = {"actor": actor.init(keys[0], s), "critic": critic.init(keys[1], s, a)}
        params["target_critic"] = jax.tree.map(jnp.copy, params["critic"])
        for k, (name, module, *inputs) in zip(keys[2:], extra):
            params[name] = module.init(k, *inputs)
        return params


def critic_fields(cfg, obs_dim: int, act_dim: int, layers: int, actor_lr: float, hidden: int = 256,
                  critic_lr: float = 3e-4) -> dict:
    """The :class:`CriticAgentBase` fields from ``cfg``, with the agent's reference ``layers``, ``hidden``,
    ``actor_lr`` and ``critic_lr`` where ``--ac-layers``, ``--ac-hidden``, ``--actor-lr``, ``--critic-lr`` are unset."""
    return dict(obs_dim=obs_dim, act_dim=act_dim, hidden=(cfg.ac_hidden or hidden,) * (cfg.ac_layers or layers),
                discount=cfg.discount, tau=cfg.tau, batch_size=cfg.critic_batch_size,
                actor_lr=cfg.actor_lr or actor_lr, critic_lr=cfg.critic_lr or critic_lr, precision=cfg.precision)
