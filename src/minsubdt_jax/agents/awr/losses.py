"""AWR's pieces (d4rl_evaluations ``awr/learning/rl_agent.py`` TD(lambda) returns, ``awr_agent.py`` losses):
lambda-returns over whole stored episodes, the value regression, and the advantage-weighted log-likelihood."""

from __future__ import annotations

import jax
import jax.numpy as jnp

WEIGHT_MAX = 20.0  # the reference's clip of exp(A / temperature)


def lambda_returns(rewards, values, lengths, last_done, discount: float, lam: float):
    """``R [N, T]``: TD(lambda) returns of every stored step, ``R_t = r_t + gamma ((1 - lambda) V(s_{t+1}) + lambda
    R_{t+1})`` backwards over each episode; after the last step ``L - 1`` the return is 0 where ``last_done`` (a
    termination, or an episodic reward) and else bootstraps from ``V(s_{L-1})`` (the data hold no final state).
    ``rewards``, ``values`` ``[N, T]`` (0 past each episode's end), ``lengths [N]``, ``last_done [N]``."""
    T = rewards.shape[1]
    t = jnp.arange(T)
    last = lengths - 1
    v_last = jnp.take_along_axis(values, last[:, None], 1)[:, 0]
    tail = (1.0 - last_done) * v_last  # the value after the last step

    def back(carry, k):  # carry: (R_{k+1}, V(s_{k+1})) per episode
        r_next, v_next = carry
        at_end = k == last
        r_next = jnp.where(at_end, tail, r_next)
        v_next = jnp.where(at_end, tail, v_next)
        ret = rewards[:, k] + discount * ((1.0 - lam) * v_next + lam * r_next)
        ret = jnp.where(k <= last, ret, 0.0)
        return (ret, values[:, k]), ret

    zeros = jnp.zeros(rewards.shape[0])
    _, out = jax.lax.scan(back, (zeros, zeros), t[::-1])
    return out[::-1].T


def advantage_weights(advantages, valid, temperature: float):
    """``min(exp(A_std / temperature), 20)`` with ``A_std`` the advantages standardised over the valid steps
    (the reference's ``_calc_adv_weights`` on its normalised advantages)."""
    n = valid.sum()
    mean = jnp.where(valid, advantages, 0.0).sum() / n
    std = jnp.sqrt(jnp.where(valid, (advantages - mean) ** 2, 0.0).sum() / n)
    return jnp.minimum(jnp.exp((advantages - mean) / (std + 1e-8) / temperature), WEIGHT_MAX)


def actor_loss(mean, actions, weights, std: float, bound_weight: float = 10.0):
    """``-mean(w log N(a; mean, std))`` (fixed std, up to a constant) plus the reference's action-bound loss
    ``bound_weight * mean(sum(max(|mean| - 1, 0)^2))``."""
    log_prob = -0.5 * jnp.sum(((actions - mean) / std) ** 2, -1)
    bound = jnp.sum(jnp.maximum(jnp.abs(mean) - 1.0, 0.0) ** 2, -1)
    return -(weights * log_prob).mean() + bound_weight * bound.mean()
