"""Behaviour cloning with an MLP on the current state: the BC of the offline-RL literature (D4RL, CORL), and
the agent that shows the slot of :mod:`minsubdt_jax.agents` holds more than the DT. It trains on windows of one
step, ignores return tokens, and has no memory in its rollouts."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import jax.numpy as jnp

from ..base import PolicyInputs, StepAgent
from .losses import bc_loss
from .networks import MLPPolicy


@dataclass(frozen=True)
class MLPAgent(StepAgent):
    obs_dim: int
    act_dim: int
    hidden: int
    layers: int
    context_len: int = 1

    @property
    def model(self) -> MLPPolicy:
        return MLPPolicy(self.act_dim, self.hidden, self.layers)

    def init_params(self, key):
        return self.model.init(key, jnp.zeros((1, self.obs_dim)))

    def loss(self, params, batch, rng):
        return bc_loss(self.model, params, batch)

    @property
    def policy(self):
        return mlp_policy(self.model)

    def initial_carry(self, n: int):
        return ()


@functools.lru_cache(maxsize=None)
def mlp_policy(model: MLPPolicy):
    """The rollout policy of ``model`` (cached per model so the compiled rollout is reused)."""

    def policy(p: PolicyInputs, carry, obs, prev_reward, t, rng):
        return carry, model.apply(p.params, (obs - p.state_mean) / p.state_std)

    return policy


def make_mlp_agent(cfg, obs_dim: int, act_dim: int, max_timestep: int) -> MLPAgent:
    return MLPAgent(obs_dim, act_dim, cfg.mlp_hidden, cfg.mlp_layers)
