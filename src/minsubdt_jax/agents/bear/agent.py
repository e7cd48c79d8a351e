"""The BEAR agent with d4rl_evaluations ``bear/`` settings (its README's D4RL commands): a tanh-Gaussian actor and
twin critics of 2 x 256 (Adam 1e-4 and 3e-4), the VAE of :mod:`.networks` (Adam 3e-4), MMD between 4 VAE and 4
policy samples on pre-tanh actions with the laplacian kernel, sigma 20, for hopper and walker and the gaussian for
halfcheetah, epsilon 0.05, a dual on log alpha (Adam 1e-3, clamped to [-5, 10]), 10 target samples, Polyak 0.005.

Choices: the MMD-only warm-up, 40k of the reference's 1M steps, is 4 % of ``--steps`` (``--pretrain-steps`` sets
it). The actor takes no entropy term (the D4RL runs' setting). Evaluation samples 100 actions from the policy
and takes the best by the first critic (``num_samples = 100`` of the launcher): a stochastic choice, seeded per
episode."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import optax

from ..actor_critic import CriticAgentBase, critic_fields
from ..base import PolicyInputs
from ...networks import Critics
from ..critic_networks import TanhGaussianActor
from .losses import bear_losses
from .networks import VAE


@dataclass(frozen=True)
class BEARAgent(CriticAgentBase):
    kernel: str = "laplacian"
    sigma: float = 20.0
    epsilon: float = 0.05
    n_mmd: int = 4
    n_target: int = 10
    n_eval: int = 100
    warmup: int = 40_000
    vae_lr: float = 3e-4
    dual_lr: float = 1e-3
    vae_hidden: tuple = (750, 750)

    @property
    def networks(self):
        return (TanhGaussianActor(self.act_dim, self.hidden, dtype=self.dtype), Critics(self.hidden, dtype=self.dtype),
                VAE(self.act_dim, self.vae_hidden, self.dtype))

    def init_params(self, key):
        actor, critic, vae = self.networks
        k, k_noise = jax.random.split(key)
        s, a = jnp.zeros((1, self.obs_dim)), jnp.zeros((1, self.act_dim))
        params = self._init(k, actor, critic, [("vae", vae, s, a, k_noise)])
        params["log_alpha"] = jnp.zeros(())
        return params

    @property
    def optimizers(self) -> dict:
        return {"vae": optax.adam(self.vae_lr), "actor": optax.adam(self.actor_lr),
                "critic": optax.adam(self.critic_lr), "log_alpha": optax.adam(self.dual_lr)}

    def losses(self, params, batch, rng, step=None):
        q_on = 1.0 if step is None else (step >= self.warmup).astype(jnp.float32)
        return bear_losses(self, params, batch, rng, q_on)

    def constrain(self, params):
        return dict(params, log_alpha=jnp.clip(params["log_alpha"], -5.0, 10.0))

    @property
    def policy(self):
        actor, critic, _ = self.networks
        return best_of_q_policy(actor, critic, self.n_eval)


@functools.lru_cache(maxsize=None)
def best_of_q_policy(actor, critic, n: int):
    """Sample ``n`` actions from the policy at each state and take the one the first critic values most."""

    def policy(p: PolicyInputs, carry, obs, prev_reward, t, rng):
        s = p.normalise(obs)
        mean, log_std = actor.apply(p.params["actor"], s)
        a = jnp.tanh(mean + jnp.exp(log_std) * jax.random.normal(rng, (n, *mean.shape)))  # [n, B, act]
        q = critic.apply(p.params["critic"], jnp.broadcast_to(s, (n, *s.shape)), a)[0]  # [n, B]
        return carry, jnp.take_along_axis(a, q.argmax(0)[None, ..., None], 0)[0]

    return policy


def make_bear_agent(cfg, obs_dim: int, act_dim: int, max_timestep: int) -> BEARAgent:
    warmup = cfg.steps // 25 if cfg.pretrain_steps is None else cfg.pretrain_steps
    return BEARAgent(**critic_fields(cfg, obs_dim, act_dim, layers=2, actor_lr=1e-4),
                     kernel=cfg.bear_kernel or "laplacian", warmup=warmup)
