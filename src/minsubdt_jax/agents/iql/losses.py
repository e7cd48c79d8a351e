"""IQL's losses (ikostrikov/implicit_q_learning ``value_net.py``, ``critic.py``, ``actor.py``), summed for one
backward pass with ``stop_gradient`` between networks."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ...data import Transitions
from ...networks import gaussian_log_prob

sg = jax.lax.stop_gradient
ADVANTAGE_WEIGHT_MAX = 100.0  # exp(beta * advantage) is clipped here (the reference's 100)


def expectile_loss(diff, expectile: float):
    """``|tau - 1(u < 0)| u^2`` elementwise, ``u = diff = Q - V`` (the reference's ``loss(diff, expectile)``)."""
    return jnp.where(diff > 0, expectile, 1.0 - expectile) * diff ** 2


def advantage_weights(advantage, beta: float):
    """``min(exp(beta * A), 100)``: the AWR weights of IQL's policy extraction."""
    return jnp.minimum(jnp.exp(beta * advantage), ADVANTAGE_WEIGHT_MAX)


def iql_losses(agent, params, batch: Transitions):
    """``{value, actor, critic}``, each a scalar: the expectile regression of ``V(s)`` onto the target critics'
    ``min_j Q'_j(s, a)``; the advantage-weighted log-likelihood of the data's action under the Gaussian actor,
    ``A = min_j Q'_j(s, a) - V(s)``; the critics' squared error to ``r + gamma (1 - done) V(s')``, summed over the
    two critics (the reference's ``((q1 - y)^2 + (q2 - y)^2).mean()``).

    The reference updates V, then the actor, then the critics, each with the networks updated just before; in one
    backward pass the actor and the critics see the V of the step's start (a lag of one step)."""
    actor, critic, value = agent.networks
    s, a = batch.states, batch.actions
    q_target = critic.apply(sg(params["target_critic"]), s, a).min(0)  # [B]
    v = value.apply(params["value"], s)
    value_loss = expectile_loss(q_target - v, agent.expectile).mean()
    weights = sg(advantage_weights(q_target - v, agent.beta))
    mean, log_std = actor.apply(params["actor"], s)
    actor_loss = -(weights * gaussian_log_prob(a, mean, log_std)).mean()
    y = sg(batch.rewards + agent.discount * (1.0 - batch.done) * value.apply(params["value"], batch.next_states))
    q = critic.apply(params["critic"], s, a)  # [2, B]
    critic_loss = ((q - y[None]) ** 2).sum(0).mean()
    return {"value": value_loss, "actor": actor_loss, "critic": critic_loss}
