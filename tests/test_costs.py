import numpy as np
import pytest

from minsubdt_jax.costs import engineered_costs, engineered_spec, spearman


def test_engineered_costs_hand_computed():
    obs = np.zeros((2, 4, 11))
    obs[0, :, 5] = 4.0   # hopper x-velocity at the top of its range: cost 0 per step
    obs[0, :, 6] = 2.0   # z-velocity: not a feature, ignored
    obs[1, :2, 5] = -1.0  # at the bottom: cost 1
    f = np.asarray(engineered_costs("hopper", obs, np.array([4, 2]), horizon=8, terminated=np.array([True, True])))
    assert engineered_spec("hopper").names == ("x_velocity", "fall")
    # trajectory 0: x 4 steps of 0, then 4 steps not lived at 1 -> 0.5; fall 4/8
    # trajectory 1: x 2 steps of 1 + 6 not lived -> 1; fall 6/8
    np.testing.assert_allclose(f, [[0.5, 0.5], [1.0, 6 / 8]])


def test_early_termination_never_looks_cheap():
    """Same gait, one falls at step 100: its costs are higher on every feature."""
    rng = np.random.default_rng(0)
    obs = np.repeat(rng.normal(size=(1, 1000, 17)), 2, axis=0)
    f = np.asarray(engineered_costs("walker", obs, np.array([1000, 100]), horizon=1000,
                                    terminated=np.array([False, True])))
    assert np.all(f[1] > f[0]) and np.all((f >= 0) & (f <= 1))


def test_a_time_out_is_not_charged_as_a_fall():
    """The same 100 steps, once ended by a fall and once cut off (a time limit of 100, or the data's end): the
    fall is charged the worst cost for the 900 steps not lived, the cut-off episode only its own steps."""
    obs = np.zeros((2, 100, 11))
    obs[:, :, 5] = 1.5  # hopper x-velocity 1.5 m/s: per-step cost (4 - 1.5) / 5 = 0.5
    f = np.asarray(engineered_costs("hopper", obs, np.array([100, 100]), horizon=1000,
                                    terminated=np.array([True, False])))
    np.testing.assert_allclose(f[0], [(100 * 0.5 + 900) / 1000, 0.9], rtol=1e-6)
    np.testing.assert_allclose(f[1], [0.5, 0.0], rtol=1e-6)


def test_the_fall_feature_never_reorders_episodes_that_did_not_fall():
    """Min-subdominance is a sum over features (eq. 2), and against a demo that fell a never-fell row's fall
    term vanishes as alpha grows, so the fall part is the same for every never-fell row: with it, those rows
    rank exactly as with x-velocity alone. Checked on random data with the exact solver."""
    from minsubdt_jax.subdominance import min_subdominance

    rng = np.random.default_rng(1)
    n = 40
    lengths = np.where(rng.random(n) < 0.5, 1000, rng.integers(50, 1000, n))
    terminated = lengths < 1000
    obs = rng.normal(1.0, 1.0, (n, 1000, 11)).astype(np.float32)
    f = np.asarray(engineered_costs("hopper", obs, lengths, 1000, terminated=terminated))
    both = np.asarray(min_subdominance(f, f, leave_one_out=True).value)
    x_only = np.asarray(min_subdominance(f[:, :1], f[:, :1], leave_one_out=True).value)
    alive = ~terminated
    np.testing.assert_allclose(both[alive] - x_only[alive], (alive.sum() - 1) / (n - 1), rtol=1e-5)
    assert np.all(f[alive, 1] == 0) and np.all(f[terminated, 1] > 0)


def test_costs_decrease_with_speed():
    obs = np.zeros((3, 10, 17))
    obs[:, :, 8] = np.array([0.0, 2.0, 5.0])[:, None]
    f = np.asarray(engineered_costs("halfcheetah", obs, np.full(3, 10), horizon=10, terminated=np.zeros(3, bool)))
    assert engineered_spec("halfcheetah").names == ("x_velocity",)
    assert f[0, 0] > f[1, 0] > f[2, 0]


def test_costs_reject_too_long():
    with pytest.raises(ValueError, match="longer"):
        engineered_costs("hopper", np.zeros((1, 5, 11)), np.array([5]), horizon=4, terminated=np.array([True]))


def test_spearman_against_hand_values():
    assert spearman([1, 2, 3, 4], [10, 20, 30, 40]) == pytest.approx(1.0)
    assert spearman([1, 2, 3, 4], [4, 3, 2, 1]) == pytest.approx(-1.0)
    # ties get average ranks: x ranks [1, 2.5, 2.5, 4] vs y ranks [1, 2, 3, 4] -> r = 0.9486833
    assert spearman([1, 2, 2, 3], [1, 2, 3, 4]) == pytest.approx(0.9486833, rel=1e-6)
    assert np.isnan(spearman([1, 1, 1], [1, 2, 3]))


def test_min_subdominance_ranks_random_hopper_like_returns(small_dataset):
    """On real MJX data the surrogate reward agrees with the true return in rank (a sanity floor)."""
    from minsubdt_jax.subdominance import min_subdominance

    f = engineered_costs("hopper", small_dataset.observations, small_dataset.lengths, 60,
                         terminated=small_dataset.terminals)
    ms = np.asarray(min_subdominance(f, f, leave_one_out=True).value)
    assert spearman(-ms, small_dataset.returns) > 0.3


def test_better_than_demonstrated_means_dominating_the_mean_demo():
    """When no demo fell (their mean fall share is 0), an episode that does not fall either still beats the mean
    demo by being faster: no feature worse, one better. Hand-built hopper episodes of 10 steps, horizon 10."""
    from minsubdt_jax.evaluation import score_episodes

    obs = np.zeros((3, 10, 11))
    obs[:, :, 5] = np.array([3.0, 1.5, 3.0])[:, None]  # x cost (4 - v) / 5: 0.2, 0.5, 0.2 (the last falls at 5)
    lengths, fell = np.array([10, 10, 5]), np.array([False, False, True])
    demos = np.array([[0.5, 0.0], [0.4, 0.0]])  # mean [0.45, 0]: nobody fell
    ev = score_episodes("hopper", obs, lengths, np.ones((3, 10)), terminated=fell, horizon=10, demo_costs=demos)
    np.testing.assert_allclose(ev.costs, [[0.2, 0.0], [0.5, 0.0], [0.6, 0.5]], rtol=1e-6)
    assert ev.beats_mean_demo.tolist() == [True, False, False]
