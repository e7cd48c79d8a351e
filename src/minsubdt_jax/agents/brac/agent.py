"""The BRAC-v agent with d4rl_evaluations ``brac/`` settings: twin critics of 300 x 300 (Adam 1e-3), a tanh-Gaussian
actor of 200 x 200 with its log-std mapped into [-5, 0] (Adam 3e-5), a behaviour policy of the same shape fitted
by maximum likelihood (Adam 5e-4), the value penalty with a 4-sample KL estimate in the critics' target and the
actor's loss, a pure min over the twin targets, Polyak 0.005 every step, no entropy term.

Choices, where the reference leaves them open or its stages do not fit one run:

- **alpha = 0.1**, fixed: the reference's example command (``run_primal.sh``); its launcher's default is 1.0 and
  D4RL says it tuned alpha without saying to what. ``--brac-alpha`` sets it. On walker medium 0.1 does not
  learn, 1.0 does but drops on one seed, 3.0 learns later and drops on one seed too (docs/convergence.md); none
  of the curves is flat.
- **The behaviour policy is pretrained inside the run**: its first ``--pretrain-steps`` steps (default a fifth of
  ``--steps``; the reference trains it in a separate 1M-step run) train only it, and it is frozen after. Its MLE
  has no entropy bonus (the reference adds a learnt one). A sharper behaviour policy raises the penalty: on walker
  medium at alpha 3.0, 28k steps of it instead of 14k delayed learning by ~70k steps (docs/convergence.md).
- **The warm start** (the actor's Q term off; 20k of the reference's 1M agent steps) is 2 % of the agent's steps.

Deterministic evaluation: ``tanh`` of the actor's mean."""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import optax

from ..actor_critic import CriticAgentBase, critic_fields, deterministic_policy
from ...networks import Critics
from ..critic_networks import TanhGaussianActor
from .losses import brac_losses

LOG_STD_RANGE = (-5.0, 0.0)


@dataclass(frozen=True)
class BRACAgent(CriticAgentBase):
    alpha: float = 0.1
    n_samples: int = 4
    pretrain_steps: int = 200_000
    warm_start: int = 20_000
    behavior_lr: float = 5e-4
    policy_hidden: tuple = (200, 200)

    @property
    def networks(self):
        return (TanhGaussianActor(self.act_dim, self.policy_hidden, LOG_STD_RANGE, self.dtype),
                Critics(self.hidden, dtype=self.dtype), TanhGaussianActor(self.act_dim, self.policy_hidden, LOG_STD_RANGE,
                                                                          self.dtype))

    def init_params(self, key):
        actor, critic, behavior = self.networks
        return self._init(key, actor, critic, [("behavior", behavior, jnp.zeros((1, self.obs_dim)))])

    @property
    def optimizers(self) -> dict:
        return {"behavior": optax.adam(self.behavior_lr), "actor": optax.adam(self.actor_lr),
                "critic": optax.adam(self.critic_lr)}

    def losses(self, params, batch, rng, step=None):
        q_on = 1.0 if step is None else (step >= self.pretrain_steps + self.warm_start).astype(jnp.float32)
        return brac_losses(self, params, batch, rng, q_on)

    def active(self, step) -> dict:
        pre = step < self.pretrain_steps
        return {"behavior": pre, "actor": ~pre, "critic": ~pre}

    def targets(self, step):
        return [("target_critic", "critic", step >= self.pretrain_steps)]

    @property
    def policy(self):
        return deterministic_policy(self.networks[0], "tanh_mean")


def make_brac_agent(cfg, obs_dim: int, act_dim: int, max_timestep: int) -> BRACAgent:
    pretrain = cfg.steps // 5 if cfg.pretrain_steps is None else cfg.pretrain_steps
    return BRACAgent(**critic_fields(cfg, obs_dim, act_dim, layers=2, actor_lr=3e-5, hidden=300, critic_lr=1e-3),
                     alpha=cfg.brac_alpha, pretrain_steps=pretrain, warm_start=max(cfg.steps - pretrain, 0) // 50)
