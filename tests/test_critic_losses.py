"""The critic agents' losses against hand computations and closed forms: IQL's expectile and advantage weights,
TD3+BC's lambda, CQL's logsumexp and temperature, BEAR's MMD, BRAC-v's KL estimate, AWR's lambda-returns and
weights (the agents' behaviour is tests/test_critics.py's)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from minsubdt_jax.agents.cql.losses import cql_logsumexp, temperature_loss
from minsubdt_jax.networks import tanh_gaussian_sample
from minsubdt_jax.agents.iql.losses import advantage_weights, expectile_loss
from minsubdt_jax.agents.td3bc.losses import bc_lambda


def test_losses_by_hand():
    # IQL: the expectile weights tau above, 1 - tau below; the AWR weights clipped at 100
    np.testing.assert_allclose(expectile_loss(jnp.array([1.0, -1.0, 2.0]), 0.7), [0.7, 0.3, 2.8], rtol=1e-6)
    np.testing.assert_allclose(advantage_weights(jnp.array([0.0, 1.0, 10.0]), 3.0), [1.0, np.exp(3.0), 100.0],
                               rtol=1e-6)
    # TD3+BC: lambda = alpha / mean |Q|, no gradient through it
    q = jnp.array([1.0, -3.0])
    assert float(bc_lambda(q, 2.5)) == pytest.approx(1.25)
    np.testing.assert_array_equal(jax.grad(lambda x: bc_lambda(x, 2.5))(q), [0.0, 0.0])
    # CQL: importance-sampled logsumexp over N uniform, N pi(s') and N pi(s) actions (N = 2, |A| = 3), brute force
    qr, qn, qc = jnp.array([[1.0], [2.0]]), jnp.array([[0.5], [-1.0]]), jnp.array([[3.0], [0.0]])
    lpn, lpc = jnp.array([[-1.0], [-2.0]]), jnp.array([[0.5], [-0.5]])
    terms = [1 - 3 * np.log(0.5), 2 - 3 * np.log(0.5), 0.5 + 1, -1 + 2, 3 - 0.5, 0 + 0.5]
    assert float(cql_logsumexp(qr, qn, qc, lpn, lpc, 3)[0]) == pytest.approx(np.log(np.sum(np.exp(terms))), rel=1e-6)
    # a constant Q = c over all actions: the penalty's logsumexp is c + log sum exp(-log rho), whatever c
    for c in (0.0, 5.0):
        full = lambda x: jnp.full((2, 1), x)  # noqa: E731
        got = cql_logsumexp(full(c), full(c), full(c), lpn, lpc, 3)[0] - c
        assert float(got) == pytest.approx(np.log(2 * 8 + np.exp(1) + np.exp(2) + np.exp(-0.5) + np.exp(0.5)), rel=1e-5)
    # SAC's temperature: -mean(log alpha (log pi + target)), d/d log alpha = -mean(log pi + target)
    lp = jnp.array([-1.0, -3.0])
    assert float(temperature_loss(0.5, lp, -2.0)) == pytest.approx(2.0)
    assert float(jax.grad(temperature_loss)(0.5, lp, -2.0)) == pytest.approx(4.0)
    # the tanh-Gaussian's log-density: change of variables, in float64 numpy
    mean, log_std = jnp.array([[0.3, -1.0]]), jnp.array([[-0.5, 0.2]])
    a, logp = tanh_gaussian_sample(jax.random.PRNGKey(0), mean, log_std)
    u = np.arctanh(np.asarray(a, np.float64))
    m, sd = np.asarray(mean, np.float64), np.exp(np.asarray(log_std, np.float64))
    ref = np.sum(-0.5 * ((u - m) / sd) ** 2 - np.log(sd) - 0.5 * np.log(2 * np.pi) - np.log(1 - np.tanh(u) ** 2), -1)
    np.testing.assert_allclose(logp, ref, rtol=1e-4)


class _Fixed:
    """A stand-in policy module: ``apply(params, states)`` gives the same Gaussian at every state."""

    def __init__(self, mean, log_std):
        self.mean, self.log_std = jnp.asarray(mean), jnp.asarray(log_std)

    def apply(self, params, states):
        shape = (*states.shape[:-1], self.mean.shape[-1])
        return jnp.broadcast_to(self.mean, shape), jnp.broadcast_to(self.log_std, shape)


def test_bear_mmd_by_hand():
    """MMD with both kernels (2 sigma in the exponent) on 2 + 1 samples at one state, by hand; MMD(X, X) = 1e-3."""
    from minsubdt_jax.agents.bear.losses import mmd

    x, y = jnp.array([[[0.0, 0.0]], [[1.0, 2.0]]]), jnp.array([[[2.0, 0.0]]])  # [n, B=1, d]
    for kernel, dist in (("laplacian", lambda a, b: np.abs(a - b).sum()),
                         ("gaussian", lambda a, b: ((a - b) ** 2).sum())):
        k = lambda a, b: np.exp(-dist(np.array(a), np.array(b)) / (2 * 20.0))  # noqa: E731
        xs, ys = [[0, 0], [1, 2]], [[2, 0]]
        kxx = np.mean([k(a, b) for a in xs for b in xs])
        kxy = np.mean([k(a, b) for a in xs for b in ys])
        want = np.sqrt(kxx + 1.0 - 2 * kxy + 1e-6)
        assert float(mmd(x, y, kernel, 20.0)[0]) == pytest.approx(want, rel=1e-5), kernel
        assert float(mmd(x, x, kernel, 20.0)[0]) == pytest.approx(1e-3, rel=1e-3)
    far = jnp.array([[[10.0, 10.0]]])
    assert float(mmd(x, far, "laplacian", 20.0)[0]) > float(mmd(x, y, "laplacian", 20.0)[0])


def test_brac_kl_estimate_against_the_closed_form():
    """KL is invariant under tanh, so the 4-sample estimate of KL(tanh N1 || tanh N2) averages to the closed form
    sum log(s2/s1) + (s1^2 + (m1 - m2)^2) / (2 s2^2) - 1/2 of the Gaussians; 0 for pi = pi_b."""
    from minsubdt_jax.agents.brac.losses import kl_estimate

    m1, l1, m2, l2 = np.array([0.1, -0.3]), np.array([-1.0, -1.5]), np.array([0.3, 0.0]), np.array([-0.7, -1.2])
    s1, s2 = np.exp(l1), np.exp(l2)
    closed = np.sum(l2 - l1 + (s1 ** 2 + (m1 - m2) ** 2) / (2 * s2 ** 2) - 0.5)
    states = jnp.zeros((20000, 3))
    est = kl_estimate(jax.random.PRNGKey(0), _Fixed(m1, l1), _Fixed(m2, l2), None, None, states, 4)
    assert float(est.mean()) == pytest.approx(closed, rel=0.02)
    same = kl_estimate(jax.random.PRNGKey(0), _Fixed(m1, l1), _Fixed(m1, l1), None, None, states[:10], 4)
    np.testing.assert_allclose(same, 0.0, atol=1e-5)
    # An actor saturated past the 1e-3 clip (pre-tanh mean 10 vs arctanh(0.999) = 3.8) is far from pi_b: with the
    # actor's own log-density taken at the clipped sample the estimate read -8e5, a reward for leaving the data
    b, sat = _Fixed(np.zeros(2), np.zeros(2)), lambda m: _Fixed(np.full(2, m), np.full(2, -5.0))
    far, near = (float(kl_estimate(jax.random.PRNGKey(1), sat(m), b, None, None, states[:10], 4).mean())
                 for m in (10, 2))
    assert far > near > 0


def test_awr_lambda_returns_and_weights_by_hand():
    """TD(lambda) returns against a float64 loop over each episode: a termination ends at 0, a time-out bootstraps
    from its last state's value; the weights are exp of the standardised advantages, clipped at 20."""
    from minsubdt_jax.agents.awr.losses import advantage_weights, lambda_returns

    r = np.random.default_rng(0)
    rewards, values = r.normal(size=(2, 5)), r.normal(size=(2, 5))
    lengths, done = np.array([5, 3]), np.array([1.0, 0.0])
    rewards[1, 3:] = values[1, 3:] = 0.0
    g, lam = 0.9, 0.95
    want = np.zeros((2, 5))
    for i in range(2):
        L = lengths[i]
        nxt_r = nxt_v = (1 - done[i]) * values[i, L - 1]
        for k in range(L - 1, -1, -1):
            want[i, k] = rewards[i, k] + g * ((1 - lam) * nxt_v + lam * nxt_r)
            nxt_r, nxt_v = want[i, k], values[i, k]
    got = lambda_returns(jnp.asarray(rewards, jnp.float32), jnp.asarray(values, jnp.float32), jnp.asarray(lengths),
                         jnp.asarray(done, jnp.float32), g, lam)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)
    adv = jnp.array([0.0, 1.0, 2.0, 100.0])
    valid = jnp.array([True, True, True, False])  # the last is padding: not in the standardisation
    w = advantage_weights(adv, valid, 1.0)
    np.testing.assert_allclose(w[:3], np.exp(np.array([-1.0, 0.0, 1.0]) / np.sqrt(2 / 3)), rtol=1e-5)
    assert float(w[3]) == 20.0
