"""Learned cost features (seed eq. 3)."""

import jax.numpy as jnp
import numpy as np
import pytest

from minsubdt_jax.learned_costs import (
    LearnedCostConfig, pair_accuracy, preference_loss, preference_pairs, train_learned_costs)


def test_preference_loss_hand_computed():
    # K' = 2, alpha = (2, 1), beta = 0.5. worse = (0.6, 0.2), better = (0.3, 0.4).
    # c_wb = [2 (0.6 - 0.3) + 0.5]_+ + [1 (0.2 - 0.4) + 0.5]_+ = 1.1 + 0.3 = 1.4
    # c_bw = [2 (0.3 - 0.6) + 0.5]_+ + [1 (0.4 - 0.2) + 0.5]_+ = 0 + 0.7 = 0.7
    # loss = -log(e^-0.7 / (e^-1.4 + e^-0.7)) = log(1 + e^{0.7 - 1.4})
    loss = preference_loss(jnp.array([[0.6, 0.2]]), jnp.array([[0.3, 0.4]]), jnp.array([2.0, 1.0]), 0.5)
    assert float(loss) == pytest.approx(np.log1p(np.exp(-0.7)), rel=1e-6)
    # swapping the roles gives log(1 + e^{+0.7}); a batch is the mean of its pairs
    both = preference_loss(jnp.array([[0.6, 0.2], [0.3, 0.4]]), jnp.array([[0.3, 0.4], [0.6, 0.2]]),
                           jnp.array([2.0, 1.0]), 0.5)
    assert float(both) == pytest.approx((np.log1p(np.exp(-0.7)) + np.log1p(np.exp(0.7))) / 2, rel=1e-6)


def test_preference_pairs_rank_by_return_and_flip_with_noise():
    returns = np.array([3.0, 1.0, 2.0, 2.0, 5.0])
    w, b = preference_pairs(returns, np.random.default_rng(0), 500)
    assert np.all(returns[w] < returns[b])
    w, b = preference_pairs(returns, np.random.default_rng(0), 4000, label_noise=0.25)
    flipped = np.mean(returns[w] > returns[b])
    assert abs(flipped - 0.25) < 0.03


def test_pair_accuracy_brute_force():
    rng = np.random.default_rng(1)
    f = rng.random((7, 2))
    r = rng.normal(size=7)
    alpha, beta = np.array([3.0, 0.5]), 0.2
    hits = []
    for i in range(7):
        for j in range(i + 1, 7):
            w, b = (i, j) if r[i] < r[j] else (j, i)
            c_wb = np.sum(np.maximum(alpha * (f[w] - f[b]) + beta, 0))
            c_bw = np.sum(np.maximum(alpha * (f[b] - f[w]) + beta, 0))
            hits.append(1.0 if c_bw < c_wb else 0.5 if c_bw == c_wb else 0.0)
    assert pair_accuracy(f, r, np.arange(7), alpha, beta) == pytest.approx(np.mean(hits))


def _synthetic(n=80, T=40, seed=0):
    """Trajectories whose true per-step cost is a known function of the state: obs[..., 0] (low = good);
    obs[..., 1] is noise. Some end early; the true return is -(sum of cost) - 1 per step not lived."""
    rng = np.random.default_rng(seed)
    level = rng.uniform(0, 1, n)
    obs = np.stack([level[:, None] + 0.1 * rng.normal(size=(n, T)), rng.normal(size=(n, T))], -1).astype(np.float32)
    lengths = np.where(rng.random(n) < 0.3, rng.integers(T // 2, T, n), T)
    valid = np.arange(T)[None] < lengths[:, None]
    obs = np.where(valid[..., None], obs, 0.0)
    returns = -(np.where(valid, obs[..., 0], 0).sum(1) + (T - lengths) * 2.0)
    return obs, lengths, returns


def test_learned_cost_recovers_the_true_ordering():
    obs, lengths, returns = _synthetic()
    cfg = LearnedCostConfig(cost_dim=2, hidden=16, steps=300, pairs_per_step=32, learning_rate=3e-3, seed=0)
    model = train_learned_costs(obs, lengths, returns, cfg, terminated=lengths < 40, horizon=40)
    rep = model.report
    assert rep["heldout_pair_accuracy"] > 0.85 and rep["train_pair_accuracy"] > 0.85
    # on fresh trajectories from the same process, the learned features order them like the true return
    obs2, len2, ret2 = _synthetic(seed=1)
    from minsubdt_jax.costs import spearman
    from minsubdt_jax.subdominance import min_subdominance

    f2 = model.features(obs2, len2, len2 < 40)
    assert f2.shape == (80, 2) and np.all((f2 >= 0) & (f2 <= 1))
    ms = np.asarray(min_subdominance(f2, f2, leave_one_out=True).value)
    assert spearman(-ms, ret2) > 0.8
    # an untrained model does not
    untrained = train_learned_costs(obs, lengths, returns, LearnedCostConfig(cost_dim=2, hidden=16, steps=1,
                                                                            learning_rate=1e-9),
                                    terminated=lengths < 40, horizon=40)
    assert untrained.report["heldout_pair_accuracy"] < rep["heldout_pair_accuracy"] - 0.1


def test_early_termination_is_never_cheaper():
    obs, lengths, returns = _synthetic(n=20)
    model = train_learned_costs(obs, lengths, returns, LearnedCostConfig(cost_dim=3, hidden=8, steps=5),
                                terminated=lengths < 40, horizon=40)
    full = model.features(obs, np.full(20, 40), np.zeros(20, bool))
    cut = model.features(obs, np.full(20, 10), np.ones(20, bool))
    assert np.all(cut >= full - 1e-6)


def test_bad_config():
    obs, lengths, returns = _synthetic(n=20)
    with pytest.raises(ValueError, match="label_noise"):
        train_learned_costs(obs, lengths, returns, LearnedCostConfig(label_noise=0.6), terminated=lengths < 40)
