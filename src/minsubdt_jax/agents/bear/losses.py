"""BEAR's losses (d4rl_evaluations ``bear/rlkit/torch/sac/bear.py``), summed for one backward pass with
``stop_gradient`` between networks."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ...data import Transitions
from ...networks import gaussian_sample
from ..critic_networks import repeat
from .networks import decode_samples

sg = jax.lax.stop_gradient


def mmd(x, y, kernel: str, sigma: float):
    """``[B]`` maximum mean discrepancy between sample sets ``x [n, B, d]`` and ``y [m, B, d]`` per state:
    ``sqrt(mean k(x, x') + mean k(y, y') - 2 mean k(x, y) + 1e-6)``, with the reference's kernels
    ``exp(-sum |x - y| / (2 sigma))`` (laplacian) and ``exp(-sum (x - y)^2 / (2 sigma))`` (gaussian): 2 sigma,
    not 2 sigma^2."""
    def k(a, b):
        diff = a[:, None] - b[None, :]  # [n, m, B, d]
        dist = jnp.abs(diff).sum(-1) if kernel == "laplacian" else (diff ** 2).sum(-1)
        return jnp.exp(-dist / (2.0 * sigma)).mean((0, 1))
    return jnp.sqrt(k(x, x) + k(y, y) - 2.0 * k(x, y) + 1e-6)


def vae_loss(recon, actions, mean, std):
    """The reference's ``MSE(recon, a) + 0.5 KL``, ``KL = -0.5 mean(1 + log std^2 - mean^2 - std^2)``."""
    kl = -0.5 * (1.0 + jnp.log(std ** 2) - mean ** 2 - std ** 2).mean()
    return ((recon - actions) ** 2).mean() + 0.5 * kl


def bear_losses(agent, params, batch: Transitions, rng, q_on):
    """``{vae, critic, actor, dual}``: the VAE's loss; the twin critics' squared errors (summed) to
    ``r + gamma (1 - done) max_10 [0.75 min_j Q'_j + 0.25 max_j Q'_j](s', a'_k)``, ``a'_k ~ pi(s')``; the actor's
    ``mean(-q_on min_j Q_j(s, a~pi) + alpha (MMD(s) - eps))`` with ``MMD`` between ``n`` VAE and ``n`` policy samples
    on pre-tanh actions (alpha and the critics detached; ``q_on`` 0 in the MMD-only warm-up); and the dual's
    ``-mean(alpha (MMD - eps))`` (MMD detached), so that log alpha ascends on the constraint."""
    actor, critic, vae = agent.networks
    s, a, s2 = batch.states, batch.actions, batch.next_states
    k_vae, k_next, k_dec, k_pi = jax.random.split(rng, 4)
    recon, mean_z, std_z = vae.apply(params["vae"], s, a, k_vae)
    loss_vae = vae_loss(recon, a, mean_z, std_z)
    m2, ls2 = actor.apply(sg(params["actor"]), s2)
    u2 = gaussian_sample(k_next, repeat(m2, agent.n_target), repeat(ls2, agent.n_target))
    q2 = critic.apply(sg(params["target_critic"]), repeat(s2, agent.n_target), jnp.tanh(u2))  # [2, n, B]
    target = (0.75 * q2.min(0) + 0.25 * q2.max(0)).max(0)
    y = sg(batch.rewards + agent.discount * (1.0 - batch.done) * target)
    loss_critic = ((critic.apply(params["critic"], s, a) - y[None]) ** 2).mean(1).sum()
    _, raw_vae = decode_samples(vae, sg(params["vae"]), k_dec, s, agent.n_mmd)
    mean, log_std = actor.apply(params["actor"], s)
    raw_pi = gaussian_sample(k_pi, repeat(mean, agent.n_mmd), repeat(log_std, agent.n_mmd))
    discrepancy = mmd(sg(raw_vae), raw_pi, agent.kernel, agent.sigma)  # [B]
    alpha = jnp.exp(params["log_alpha"])
    q_pi = critic.apply(sg(params["critic"]), s, jnp.tanh(raw_pi[0])).min(0)
    loss_actor = (-q_on * q_pi + sg(alpha) * (discrepancy - agent.epsilon)).mean()
    loss_dual = -(alpha * sg(discrepancy - agent.epsilon)).mean()
    return {"vae": loss_vae, "critic": loss_critic, "actor": loss_actor, "dual": loss_dual}
