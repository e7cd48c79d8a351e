"""Cost features learned from pairwise preferences over demonstrations (seed eq. 3).

A Flax MLP ``f_psi: state -> [0, 1]^{K'}`` (sigmoid output, so the scale of the features is fixed) gives a
per-step cost; a trajectory's features average it over the horizon ``H`` and charge every step it did not
live the worst per-step cost, 1, exactly like the engineered features (``minsubdt_jax.costs``):

    f_k(xi) = 1/H * ( sum_{t < L} f_psi,k(s_t) + (H - L) )     (terminated; a trajectory cut off: 1/L sum_{t<L})

so ending an episode early can never make a trajectory cheaper. Preferences ``xi_i < xi_j`` (``j`` preferred)
come from the trajectories' true returns (T-REX style: random pairs, the higher return preferred, optional
label noise). Eq. 3's loss for a pair is ``-log(e^{-c_ji} / (e^{-c_ij} + e^{-c_ji})) = softplus(c_ji - c_ij)``
with ``c_ij = subdom_{alpha, beta}(f(xi_i), f(xi_j))`` (eq. 1). If alpha were minimised per pair, ``c`` would
be a step function of psi with no useful gradient (``shared/NOTES.md``), so ``beta`` is the run's fixed
margin and ``alpha`` one global, learned, positive sensitivity per feature (``alpha = exp(log_alpha)``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from .costs import horizon_average, spearman
from .subdominance import subdominance


class CostNet(nn.Module):
    """Per-step learned cost ``f_psi(s) in [0, 1]^{cost_dim}``: an MLP on normalised states."""

    cost_dim: int
    hidden: int = 64
    layers: int = 2

    @nn.compact
    def __call__(self, states):
        h = states
        for _ in range(self.layers):
            h = nn.relu(nn.Dense(self.hidden)(h))
        return nn.sigmoid(nn.Dense(self.cost_dim)(h))


@dataclass(frozen=True)
class LearnedCostConfig:
    """Training of the learned costs. ``pairs_per_step`` preference pairs per Adam step; ``holdout`` the share
    of trajectories whose pairs are kept for the held-out accuracy; ``label_noise`` flips a pair's label
    with that probability (T-REX's noisy-preference setting)."""

    cost_dim: int = 2
    hidden: int = 64
    steps: int = 1000
    pairs_per_step: int = 32
    learning_rate: float = 1e-3
    init_alpha: float = 10.0
    holdout: float = 0.2
    label_noise: float = 0.0
    seed: int = 0


@struct.dataclass
class CostParams:
    """Learned cost parameters: the network's, ``log_alpha [K']``, and state normalisation ``[obs]``."""

    net: Any
    log_alpha: jax.Array
    state_mean: jax.Array
    state_std: jax.Array


def trajectory_features(net: CostNet, params: CostParams, observations, lengths, terminated, horizon: int):
    """Learned trajectory features (module docstring).

    Args:
      observations: ``[N, T, obs]`` padded states; lengths: ``[N]`` valid steps, each ``<= horizon``;
      terminated: ``[N]`` ended by termination (else cut off: not charged for the steps it was not given).
    Returns:
      ``[N, K']`` features in ``[0, 1]``, lower is better.
    """
    per_step = net.apply(params.net, (observations - params.state_mean) / params.state_std)  # [N, T, K']
    return horizon_average(per_step, lengths, horizon, terminated)


def preference_loss(f_worse, f_better, alpha, beta):
    """Eq. 3 for pairs ``worse < better``: mean of ``-log(e^{-c_bw} / (e^{-c_wb} + e^{-c_bw}))``.

    Args:
      f_worse, f_better: ``[P, K']`` features of the less and the more preferred trajectory of each pair.
      alpha, beta: ``[K']`` (or scalars) sensitivity and margin of eq. 1.
    Returns:
      scalar loss; ``c_wb = subdom(f_worse, f_better)``, ``c_bw = subdom(f_better, f_worse)``.
    """
    c_wb = subdominance(f_worse, f_better, alpha, beta)
    c_bw = subdominance(f_better, f_worse, alpha, beta)
    return jnp.mean(jax.nn.softplus(c_bw - c_wb))


def preference_pairs(returns, rng: np.random.Generator, n_pairs: int, label_noise: float = 0.0):
    """``(worse [P], better [P])`` indices of random pairs of distinct-return trajectories, ranked by return;
    each label flipped with probability ``label_noise``."""
    returns = np.asarray(returns)
    n = len(returns)
    i = rng.integers(0, n, 4 * n_pairs)
    j = rng.integers(0, n, 4 * n_pairs)
    keep = returns[i] != returns[j]
    i, j = i[keep][:n_pairs], j[keep][:n_pairs]
    if len(i) < n_pairs:
        raise ValueError("too few trajectories with distinct returns to draw preference pairs")
    worse, better = np.where(returns[i] < returns[j], i, j), np.where(returns[i] < returns[j], j, i)
    flip = rng.random(n_pairs) < label_noise
    return np.where(flip, better, worse), np.where(flip, worse, better)


@dataclass
class LearnedCosts:
    """A trained cost model: ``features(observations, lengths)`` -> ``[N, K']``, plus its training report."""

    net: CostNet
    params: CostParams
    horizon: int
    report: dict

    def features(self, observations, lengths, terminated):
        return np.asarray(_features_jit(self.net, self.horizon)(self.params, jnp.asarray(observations),
                                                                 jnp.asarray(lengths), jnp.asarray(terminated, bool)))


@functools.lru_cache(maxsize=None)
def _features_jit(net, horizon):
    """One compiled :func:`trajectory_features` per (net, horizon), reused by every ``features`` call."""
    return jax.jit(lambda p, o, l, d: trajectory_features(net, p, o, l, d, horizon))


def train_learned_costs(observations, lengths, returns, cfg: LearnedCostConfig, *, terminated, beta=1.0,
                        horizon: int = 1000, state_mean=None, state_std=None, verbose: bool = False) -> LearnedCosts:
    """Learn ``f_psi`` and ``alpha`` by eq. 3 on pairs ranked by ``returns``; report held-out accuracy.

    Args:
      observations: ``[N, T, obs]`` padded trajectories; lengths ``[N]``; returns ``[N]`` true returns (used
        only to rank pairs); terminated ``[N]`` ended by termination (see :func:`trajectory_features`).
    Returns:
      :class:`LearnedCosts`; ``report`` has the training and held-out pair accuracy (share of pairs whose
      preferred trajectory has the lower subdominance against the other, ``c_bw < c_wb``) and the final loss.
    """
    observations = np.asarray(observations, np.float32)
    lengths, terminated, returns = np.asarray(lengths), np.asarray(terminated, bool), np.asarray(returns)
    _check(cfg, len(returns))
    rng = np.random.default_rng(cfg.seed)  # the split first, then every chunk's pairs
    perm = rng.permutation(len(returns))
    n_test = max(2, int(round(cfg.holdout * len(returns))))
    test, train = perm[:n_test], perm[n_test:]
    if state_mean is None:
        valid = np.arange(observations.shape[1])[None, :] < lengths[:, None]
        state_mean, state_std = observations[valid].mean(0), observations[valid].std(0) + 1e-6
    net = CostNet(cfg.cost_dim, cfg.hidden)
    params = CostParams(net=net.init(jax.random.PRNGKey(cfg.seed), observations[:1, :1]),
                        log_alpha=jnp.full((cfg.cost_dim,), np.log(cfg.init_alpha), jnp.float32),
                        state_mean=jnp.asarray(state_mean, jnp.float32), state_std=jnp.asarray(state_std, jnp.float32))
    tx, beta = optax.adam(cfg.learning_rate), jnp.asarray(beta, jnp.float32)
    chunk = _make_chunk(net, tx, jnp.asarray(observations), jnp.asarray(lengths), jnp.asarray(terminated, bool),
                        beta, horizon)
    params, losses = _fit(chunk, params, tx, cfg, returns, train, rng, verbose)
    model = LearnedCosts(net, params, horizon, {})
    feats = model.features(observations, lengths, terminated)
    alpha, beta = np.exp(np.asarray(params.log_alpha)), float(beta)
    model.report = {
        "config": {k: getattr(cfg, k) for k in cfg.__dataclass_fields__},
        "alpha": alpha.tolist(), "beta": beta,
        "final_loss": float(np.mean(losses[-1][-50:])),
        "train_pair_accuracy": pair_accuracy(feats, returns, train, alpha, beta),
        "heldout_pair_accuracy": pair_accuracy(feats, returns, test, alpha, beta),
        "train_trajectories": int(len(train)), "heldout_trajectories": int(len(test)),
        "spearman_mean_feature_vs_return": spearman(-feats.mean(1), returns),
    }
    return model


def _check(cfg: LearnedCostConfig, n: int) -> None:
    if cfg.cost_dim < 1 or cfg.steps < 1 or cfg.pairs_per_step < 1 or not 0 <= cfg.label_noise < 0.5:
        raise ValueError("learned costs need cost_dim >= 1, steps >= 1, pairs_per_step >= 1, 0 <= label_noise < 0.5")
    if not 0 < cfg.holdout < 1 or n < 4:
        raise ValueError(f"need 0 < holdout < 1 and at least 4 trajectories, got holdout {cfg.holdout}, N {n}")


def _trainable(p: CostParams):
    return p.net, p.log_alpha


def _make_chunk(net, tx, obs, lengths, terminated, beta, horizon: int):
    """A jitted ``lax.scan`` of Adam steps on eq. 3: ``(params, opt_state, W [n, P], B [n, P])`` -> ``(params,
    opt_state, losses [n])``, ``W``/``B`` the worse/better trajectory of each step's ``P`` pairs."""

    def loss_fn(tp, p, w, b):
        p = p.replace(net=tp[0], log_alpha=tp[1])
        idx = jnp.concatenate([w, b])
        f = trajectory_features(net, p, obs[idx], lengths[idx], terminated[idx], horizon)
        return preference_loss(f[: w.shape[0]], f[w.shape[0]:], jnp.exp(p.log_alpha), beta)

    @jax.jit
    def chunk(params, opt_state, W, B):
        def step(carry, wb):
            params, opt_state = carry
            loss, g = jax.value_and_grad(loss_fn)(_trainable(params), params, *wb)
            upd, opt_state = tx.update(g, opt_state)
            net_p, log_alpha = optax.apply_updates(_trainable(params), upd)
            return (params.replace(net=net_p, log_alpha=log_alpha), opt_state), loss

        (params, opt_state), losses = jax.lax.scan(step, (params, opt_state), (W, B))
        return params, opt_state, losses

    return chunk


def _fit(chunk, params, tx, cfg: LearnedCostConfig, returns, train, rng, verbose: bool):
    """``cfg.steps`` steps in chunks of up to 250, each chunk's pairs drawn from ``train`` by ``rng``;
    ``(params, [losses per chunk])``."""
    opt_state = tx.init(_trainable(params))
    done, losses = 0, []
    while done < cfg.steps:
        n = min(250, cfg.steps - done)
        w, b = preference_pairs(returns[train], rng, n * cfg.pairs_per_step, cfg.label_noise)
        W, B = train[w].reshape(n, cfg.pairs_per_step), train[b].reshape(n, cfg.pairs_per_step)
        params, opt_state, ls = chunk(params, opt_state, jnp.asarray(W), jnp.asarray(B))
        losses.append(np.asarray(ls))
        done += n
        if verbose:
            print(f"learned costs: step {done}/{cfg.steps}, eq. 3 loss {float(np.mean(ls)):.4f}", flush=True)
    return params, losses


def pair_accuracy(features, returns, idx, alpha, beta) -> float:
    """Share of all pairs of distinct return among trajectories ``idx`` whose preferred member has the lower
    subdominance against the other (``c_bw < c_wb``); ties count one half."""
    idx = np.asarray(idx)
    f, r = np.asarray(features)[idx], np.asarray(returns)[idx]
    i, j = np.triu_indices(len(idx), 1)
    keep = r[i] != r[j]
    i, j = i[keep], j[keep]
    if len(i) == 0:
        return float("nan")
    w, b = np.where(r[i] < r[j], i, j), np.where(r[i] < r[j], j, i)
    c_wb = np.asarray(subdominance(f[w], f[b], alpha, beta))
    c_bw = np.asarray(subdominance(f[b], f[w], alpha, beta))
    return float(np.mean((c_bw < c_wb) + 0.5 * (c_bw == c_wb)))
