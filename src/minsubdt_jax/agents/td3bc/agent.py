"""The TD3+BC agent with sfujim/TD3_BC's settings: 2 x 256 networks, Adam 3e-4 for actor and critics, alpha 2.5,
target-policy noise 0.2 clipped at 0.5, the actor and both targets updated every second step (Polyak 0.005),
normalised states, no reward scaling. Deterministic evaluation: the actor's action."""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import optax

from ..actor_critic import CriticAgentBase, critic_fields, deterministic_policy
from ...networks import Critics
from ..critic_networks import DeterministicActor
from .losses import td3bc_losses


@dataclass(frozen=True)
class TD3BCAgent(CriticAgentBase):
    alpha: float = 2.5
    policy_noise: float = 0.2
    noise_clip: float = 0.5
    policy_freq: int = 2

    @property
    def networks(self):
        return DeterministicActor(self.act_dim, self.hidden, self.dtype), Critics(self.hidden, dtype=self.dtype)

    def init_params(self, key):
        params = self._init(key, *self.networks)
        params["target_actor"] = jax.tree.map(jnp.copy, params["actor"])
        return params

    @property
    def optimizers(self) -> dict:
        return {"actor": optax.adam(self.actor_lr), "critic": optax.adam(self.critic_lr)}

    def losses(self, params, batch, rng, step=None):
        return td3bc_losses(self, params, batch, rng)

    def actor_step(self, step):
        """The reference counts its iterations from 1 and updates the actor when the count divides by 2."""
        return (step + 1) % self.policy_freq == 0

    def active(self, step) -> dict:
        return {"actor": self.actor_step(step)}

    def targets(self, step):
        on = self.actor_step(step)
        return [("target_critic", "critic", on), ("target_actor", "actor", on)]

    @property
    def policy(self):
        return deterministic_policy(self.networks[0], "action")


def make_td3bc_agent(cfg, obs_dim: int, act_dim: int, max_timestep: int) -> TD3BCAgent:
    return TD3BCAgent(**critic_fields(cfg, obs_dim, act_dim, layers=2, actor_lr=3e-4), alpha=cfg.td3bc_alpha)
