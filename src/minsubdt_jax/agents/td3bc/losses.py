"""TD3+BC's losses (sfujim/TD3_BC ``TD3_BC.py``), summed for one backward pass with ``stop_gradient`` between
networks."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ...data import Transitions

sg = jax.lax.stop_gradient


def bc_lambda(q_pi, alpha: float):
    """``lambda = alpha / mean |Q(s, pi(s))|`` over the batch, with no gradient through it; the mean is floored at
    1e-6 (the reference has no floor: a critic that outputs exactly 0, as a fresh one on zero inputs does, would
    give an infinite lambda)."""
    return sg(alpha / jnp.maximum(jnp.abs(q_pi).mean(), 1e-6))


def td3bc_losses(agent, params, batch: Transitions, rng):
    """``{critic, actor}``: the twin critics' squared errors (summed) to ``r + gamma (1 - done) min_j Q'_j(s', a')``
    with ``a' = clip(pi'(s') + clip(N(0, 0.2^2), +-0.5), +-1)`` from the target actor; the actor's
    ``-lambda mean Q_1(s, pi(s)) + mean (pi(s) - a)^2`` (the mean over batch and action dims, ``F.mse_loss``)."""
    actor, critic = agent.networks
    s, a = batch.states, batch.actions
    noise = jnp.clip(agent.policy_noise * jax.random.normal(rng, a.shape), -agent.noise_clip, agent.noise_clip)
    a_next = jnp.clip(actor.apply(sg(params["target_actor"]), batch.next_states) + noise, -1.0, 1.0)
    q_next = critic.apply(sg(params["target_critic"]), batch.next_states, a_next).min(0)
    y = sg(batch.rewards + agent.discount * (1.0 - batch.done) * q_next)
    critic_loss = ((critic.apply(params["critic"], s, a) - y[None]) ** 2).mean(1).sum()
    pi = actor.apply(params["actor"], s)
    q_pi = critic.apply(sg(params["critic"]), s, pi)[0]
    actor_loss = -bc_lambda(q_pi, agent.alpha) * q_pi.mean() + ((pi - a) ** 2).mean()
    return {"critic": critic_loss, "actor": actor_loss}
