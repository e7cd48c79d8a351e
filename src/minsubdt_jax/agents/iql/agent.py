"""The IQL agent: its networks (2 x 256 everywhere), optimisers (Adam 3e-4; the actor's rate decays by a cosine to 0
over the run's ``--steps``), Polyak rate 0.005, expectile 0.7 and beta 3 of ikostrikov/implicit_q_learning
``configs/mujoco_config.py``; rewards are scaled by 1000 / (max - min episode return) (its ``train_offline.py``),
done by :mod:`minsubdt_jax.methods` (``rtg_scale=None``). Deterministic evaluation: the Gaussian's mean."""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import optax

from ..actor_critic import CriticAgentBase, critic_fields, deterministic_policy
from ...networks import Critics
from ..critic_networks import TanhMeanGaussianActor, Value
from .losses import iql_losses


@dataclass(frozen=True)
class IQLAgent(CriticAgentBase):
    steps: int = 1_000_000
    expectile: float = 0.7
    beta: float = 3.0

    @property
    def networks(self):
        return (TanhMeanGaussianActor(self.act_dim, self.hidden, self.dtype), Critics(self.hidden, dtype=self.dtype),
                Value(self.hidden, self.dtype))

    def init_params(self, key):
        actor, critic, value = self.networks
        return self._init(key, actor, critic, [("value", value, jnp.zeros((1, self.obs_dim)))])

    @property
    def optimizers(self) -> dict:
        decay = optax.cosine_decay_schedule(-self.actor_lr, self.steps)
        return {"actor": optax.chain(optax.scale_by_adam(), optax.scale_by_schedule(decay)),
                "critic": optax.adam(self.critic_lr), "value": optax.adam(self.critic_lr)}

    def losses(self, params, batch, rng, step=None):
        return iql_losses(self, params, batch)

    @property
    def policy(self):
        return deterministic_policy(self.networks[0], "mean")


def make_iql_agent(cfg, obs_dim: int, act_dim: int, max_timestep: int) -> IQLAgent:
    return IQLAgent(**critic_fields(cfg, obs_dim, act_dim, layers=2, actor_lr=3e-4), steps=cfg.steps,
                    expectile=cfg.iql_expectile, beta=cfg.iql_beta)
