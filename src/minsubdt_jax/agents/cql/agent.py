"""The CQL agent with CORL's locomotion settings (``configs/offline/cql/*``): a tanh-Gaussian actor and twin
critics of 3 x 256, Adam 3e-5 for the actor and the temperature and 3e-4 for the critics, automatic entropy with
target ``-|A|`` (``log alpha`` from 0), no entropy in the backup, conservative weight 10 with 10 actions per kind,
importance sampling, no Lagrange, no BC warm-up, Polyak 0.005 every step, normalised states, no reward scaling.
Deterministic evaluation: ``tanh`` of the mean."""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import optax

from ..actor_critic import CriticAgentBase, critic_fields, deterministic_policy
from ...networks import Critics
from ..critic_networks import TanhGaussianActor
from .losses import cql_losses


@dataclass(frozen=True)
class CQLAgent(CriticAgentBase):
    cql_alpha: float = 10.0
    n_actions: int = 10

    @property
    def networks(self):
        return TanhGaussianActor(self.act_dim, self.hidden, dtype=self.dtype), Critics(self.hidden, dtype=self.dtype)

    def init_params(self, key):
        params = self._init(key, *self.networks)
        params["log_alpha"] = jnp.zeros(())
        return params

    @property
    def optimizers(self) -> dict:
        return {"actor": optax.adam(self.actor_lr), "critic": optax.adam(self.critic_lr),
                "log_alpha": optax.adam(self.actor_lr)}

    def losses(self, params, batch, rng, step=None):
        return cql_losses(self, params, batch, rng)

    @property
    def policy(self):
        return deterministic_policy(self.networks[0], "tanh_mean")


def make_cql_agent(cfg, obs_dim: int, act_dim: int, max_timestep: int) -> CQLAgent:
    return CQLAgent(**critic_fields(cfg, obs_dim, act_dim, layers=3, actor_lr=3e-5), cql_alpha=cfg.cql_alpha,
                    n_actions=cfg.cql_actions)
