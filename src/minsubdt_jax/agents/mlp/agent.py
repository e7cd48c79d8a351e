"""Behaviour cloning with an MLP on the current state: the BC of the offline-RL literature (D4RL, CORL), and
the agent that shows the slot of :mod:`minsubdt_jax.agents` holds more than the DT. It trains on windows of one
step and has no memory in its rollouts. With ``return_dim`` R > 0 it also reads a return token per cost metric
(RvS; PEDA's MORvS: an MLP on state, preference and return target), constant over an episode as a vector method's
is; otherwise it ignores return tokens."""

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
    return_dim: int = 0
    context_len: int = 1

    @property
    def model(self) -> MLPPolicy:
        return MLPPolicy(self.act_dim, self.hidden, self.layers)

    def init_params(self, key):
        return self.model.init(key, jnp.zeros((1, self.obs_dim + self.return_dim)))

    def loss(self, params, batch, rng):
        return bc_loss(self.model, params, batch, self.return_dim)

    @property
    def policy(self):
        return mlp_policy(self.model, self.return_dim)

    def initial_carry(self, n: int):
        return ()


@functools.lru_cache(maxsize=None)
def mlp_policy(model: MLPPolicy, return_dim: int = 0):
    """The rollout policy of ``model`` (cached per model so the compiled rollout is reused); a return-conditioned
    one reads the target, scaled as in training (a vector method's rewards are paid at the end: it stays put)."""

    def policy(p: PolicyInputs, carry, obs, prev_reward, t, rng):
        x = p.normalise(obs)
        if return_dim:
            x = jnp.concatenate([x, jnp.broadcast_to(p.target_return / p.rtg_scale, x.shape[:-1] + (return_dim,))], -1)
        return carry, model.apply(p.params, x)

    return policy


def make_mlp_agent(cfg, obs_dim: int, act_dim: int, max_timestep: int, return_dim: int = 0) -> MLPAgent:
    return MLPAgent(obs_dim, act_dim, cfg.mlp_hidden, cfg.mlp_layers, return_dim)
