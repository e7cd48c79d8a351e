"""BRAC-v's losses (d4rl_evaluations ``brac/brac_primal_agent.py``, ``divergences.py``), summed for one backward
pass with ``stop_gradient`` between networks, and its behaviour policy's maximum likelihood (``bc_agent.py``)."""

from __future__ import annotations

import jax

from ...data import Transitions
from ...networks import tanh_gaussian_sample
from ..critic_networks import repeat, tanh_gaussian_log_prob

sg = jax.lax.stop_gradient


def kl_estimate(rng, actor, behavior, actor_params, behavior_params, states, n: int):
    """``D(s) [B]``: the ``n``-sample estimate of KL(pi(.|s) || pi_b(.|s)), the mean over ``a ~ pi(.|s)`` of
    ``log pi(a|s) - log pi_b(a|s)`` (``divergences.py``, ``FDivergence.primal_estimate``): ``log pi`` from the
    sample's own pre-tanh value, ``log pi_b`` at the sample clipped 1e-3 inside the action bounds (``CLIP_EPS``).
    Clipping the actor's own term too would let an actor whose mean runs past the clip drive its ``log pi`` and
    the estimate to -1e5 and below, a reward for leaving the data. Reparameterised: the gradient reaches
    ``actor_params``."""
    mean, log_std = actor.apply(actor_params, states)
    mean_b, log_std_b = behavior.apply(behavior_params, states)
    mean, log_std, mean_b, log_std_b = (repeat(x, n) for x in (mean, log_std, mean_b, log_std_b))
    a, log_pi = tanh_gaussian_sample(rng, mean, log_std)
    return (log_pi - tanh_gaussian_log_prob(a, mean_b, log_std_b)).mean(0)


def brac_losses(agent, params, batch: Transitions, rng, q_on):
    """``{behavior, critic, actor}``: the behaviour policy's negative log-likelihood of the data's actions; the twin
    critics' squared errors (summed) to ``r + gamma (1 - done) (min_j Q'_j(s', a') - alpha D(s'))``, ``a' ~ pi(s')``;
    the actor's ``mean(alpha D(s) - q_on * min_j Q_j(s, a~pi(s)))`` (the critics and pi_b detached; ``q_on`` 0
    during the warm start, then 1). The behaviour policy is pretrained first: ``agent.active`` freezes the others
    meanwhile."""
    actor, critic, behavior = agent.networks
    s, a, s2 = batch.states, batch.actions, batch.next_states
    k1, k2, k3, k4 = jax.random.split(rng, 4)
    mean_b, log_std_b = behavior.apply(params["behavior"], s)
    behavior_loss = -tanh_gaussian_log_prob(a, mean_b, log_std_b).mean()
    frozen_b, frozen_pi = sg(params["behavior"]), sg(params["actor"])
    m2, ls2 = actor.apply(frozen_pi, s2)
    a2, _ = tanh_gaussian_sample(k1, m2, ls2)
    penalty_next = kl_estimate(k2, actor, behavior, frozen_pi, frozen_b, s2, agent.n_samples)
    q_next = critic.apply(sg(params["target_critic"]), s2, a2).min(0) - agent.alpha * penalty_next
    y = sg(batch.rewards + agent.discount * (1.0 - batch.done) * q_next)
    critic_loss = ((critic.apply(params["critic"], s, a) - y[None]) ** 2).mean(1).sum()
    mean, log_std = actor.apply(params["actor"], s)
    a_pi, _ = tanh_gaussian_sample(k3, mean, log_std)
    penalty = kl_estimate(k4, actor, behavior, params["actor"], frozen_b, s, agent.n_samples)
    q_pi = critic.apply(sg(params["critic"]), s, a_pi).min(0)
    actor_loss = (agent.alpha * penalty - q_on * q_pi).mean()
    return {"behavior": behavior_loss, "critic": critic_loss, "actor": actor_loss}
