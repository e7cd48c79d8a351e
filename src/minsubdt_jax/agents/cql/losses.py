"""CQL's losses (CORL ``algorithms/offline/cql.py``, ``ContinuousCQL``; JaxCQL ``conservative_sac.py``), summed for
one backward pass with ``stop_gradient`` between networks (JaxCQL takes one backward pass per loss)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ...data import Transitions
from ...networks import tanh_gaussian_sample
from ..critic_networks import repeat

sg = jax.lax.stop_gradient


def cql_logsumexp(q_rand, q_next, q_cur, logp_next, logp_cur, act_dim: int, temperature: float = 1.0):
    """CQL(H)'s importance-sampled ``T logsumexp_k [(Q(s, a_k) - log rho(a_k)) / T]`` over the ``3N`` sampled
    actions, ``[..., B]``: ``q_*`` ``[..., N, B]`` at ``N`` uniform actions in ``[-1, 1]`` (``rho = 0.5^|A|``), ``N``
    from ``pi(s')`` and ``N`` from ``pi(s)`` (all evaluated at ``s``), ``logp_*`` ``[N, B]`` their (detached)
    log-densities. The data's action is not in the set (importance sampling on)."""
    log_rho_uniform = act_dim * jnp.log(0.5)
    cat = jnp.concatenate([q_rand - log_rho_uniform, q_next - sg(logp_next), q_cur - sg(logp_cur)], axis=-2)
    return temperature * jax.nn.logsumexp(cat / temperature, axis=-2)


def temperature_loss(log_alpha, log_prob, target_entropy: float):
    """SAC's automatic entropy tuning: ``-mean(log alpha * (log pi + target_entropy))``, ``log pi`` detached."""
    return -(log_alpha * sg(log_prob + target_entropy)).mean()


def cql_losses(agent, params, batch: Transitions, rng):
    """``{actor, temperature, td, conservative}``: SAC's actor loss ``mean(alpha log pi(a~|s) - min_j Q_j(s, a~))``
    (alpha and the critics detached) and its temperature loss; the critics' squared errors (summed) to
    ``r + gamma (1 - done) min_j Q'_j(s', a')``, ``a' ~ pi(s')``, with no entropy term in the backup; and
    ``cql_alpha * sum_j mean_B(logsumexp_j - Q_j(s, a))`` (:func:`cql_logsumexp`)."""
    actor, critic = agent.networks
    s, a, s_next = batch.states, batch.actions, batch.next_states
    k_pi, k_next, k_rand, k_cur, k_cur_next = jax.random.split(rng, 5)
    alpha = jnp.exp(params["log_alpha"])
    mean, log_std = actor.apply(params["actor"], s)
    pi, logp = tanh_gaussian_sample(k_pi, mean, log_std)
    temp_loss = temperature_loss(params["log_alpha"], logp, -float(agent.act_dim))
    actor_loss = (sg(alpha) * logp - critic.apply(sg(params["critic"]), s, pi).min(0)).mean()
    frozen = sg(params["actor"])
    mean_next, log_std_next = actor.apply(frozen, s_next)
    a_next, _ = tanh_gaussian_sample(k_next, mean_next, log_std_next)
    q_next = critic.apply(sg(params["target_critic"]), s_next, a_next).min(0)
    y = sg(batch.rewards + agent.discount * (1.0 - batch.done) * q_next)
    q_data = critic.apply(params["critic"], s, a)  # [2, B]
    td_loss = ((q_data - y[None]) ** 2).mean(1).sum()
    n, (b, act) = agent.n_actions, a.shape
    tile = lambda x: repeat(sg(x), n)  # noqa: E731  (the penalty's samples: no gradient into the actor's outputs)
    a_rand = jax.random.uniform(k_rand, (n, b, act), minval=-1.0, maxval=1.0)
    a_cur, logp_cur = tanh_gaussian_sample(k_cur, tile(mean), tile(log_std))
    a_cur_next, logp_cur_next = tanh_gaussian_sample(k_cur_next, tile(mean_next), tile(log_std_next))
    s_tiled = tile(s)
    q_ood = cql_logsumexp(critic.apply(params["critic"], s_tiled, a_rand),
                          critic.apply(params["critic"], s_tiled, sg(a_cur_next)),  # pi(s') at s, as the original
                          critic.apply(params["critic"], s_tiled, sg(a_cur)), logp_cur_next, logp_cur, act)
    conservative = agent.cql_alpha * (q_ood - q_data).mean(1).sum()
    return {"actor": actor_loss, "temperature": temp_loss, "td": td_loss, "conservative": conservative}
