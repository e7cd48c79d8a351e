"""experiments/curves_report.py: the fitted change over a curve's last third against a second method, a least-squares
fit with a dummy column per seed and its covariance sigma^2 (X^T X)^-1."""

import importlib.util
import os

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_trend_is_the_seed_fixed_effects_least_squares_slope():
    path = os.path.join(ROOT, "experiments", "curves_report.py")
    spec = importlib.util.spec_from_file_location("curves_report", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    steps = np.array([7000.0, 8000.0, 9000.0, 10000.0])
    scores = np.random.default_rng(0).normal(50, 5, (3, 4)) + np.array([[0.0], [20.0], [-10.0]])
    change, se = mod.trend(steps, scores)
    S, E = scores.shape
    X = np.zeros((S * E, S + 1))
    X[np.arange(S * E), np.repeat(np.arange(S), E)] = 1.0
    X[:, S] = np.tile(steps, S)
    coef, res, *_ = np.linalg.lstsq(X, scores.ravel(), rcond=None)
    cov = res[0] / (S * E - S - 1) * np.linalg.inv(X.T @ X)
    np.testing.assert_allclose(change, coef[S] * 3000.0, rtol=1e-9)
    np.testing.assert_allclose(se, np.sqrt(cov[S, S]) * 3000.0, rtol=1e-9)
    # a curve that rises by exactly 6 points over the third, whatever each seed's level: no residual
    change, se = mod.trend(steps, np.array([[0.0], [40.0], [7.0]]) + 2e-3 * (steps - 7000.0))
    np.testing.assert_allclose([change, se], [6.0, 0.0], atol=1e-9)
