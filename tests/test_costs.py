import numpy as np
import pytest

from minsubdt_jax.costs import engineered_costs, engineered_spec, spearman


def test_engineered_costs_hand_computed():
    obs = np.zeros((2, 4, 11))
    obs[0, :, 5] = 4.0   # hopper x-velocity at the top of its range: cost 0 per step
    obs[0, :, 6] = 2.0   # z-velocity at the top: cost 0
    obs[1, :2, 5] = -1.0  # at the bottom: cost 1
    f = np.asarray(engineered_costs("hopper", obs, np.array([4, 2]), horizon=8, terminated=np.array([True, True])))
    # trajectory 0: 4 steps of 0, then 4 padded steps of 1 -> 0.5 ; trajectory 1: x 2 steps of 1 + 6 -> 1
    # z for trajectory 1: 2 steps at v=0 -> 0.5 each, + 6 padded -> (1 + 6)/8
    np.testing.assert_allclose(f, [[0.5, 0.5], [1.0, 7 / 8]])


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
    obs[:, :, 6] = 0.0  # z-velocity 0: cost 0.5
    f = np.asarray(engineered_costs("hopper", obs, np.array([100, 100]), horizon=1000,
                                    terminated=np.array([True, False])))
    np.testing.assert_allclose(f[0], [(100 * 0.5 + 900) / 1000] * 2, rtol=1e-6)
    np.testing.assert_allclose(f[1], [0.5, 0.5], rtol=1e-6)


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
