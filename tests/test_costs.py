import numpy as np
import pytest

import jax.numpy as jnp

from minsubdt_jax.costs import (CostMetric, cost_metrics, default_costs, engineered_costs, metric, spearman,
                                trajectory_costs)


def test_engineered_costs_hand_computed():
    obs = np.zeros((2, 4, 11))
    obs[0, :, 5] = 4.0   # hopper x-velocity at the top of its range: cost 0 per step
    obs[0, :, 6] = 2.0   # z-velocity: not a feature, ignored
    obs[1, :2, 5] = -1.0  # at the bottom: cost 1
    f = np.asarray(engineered_costs("hopper", obs, np.array([4, 2]), horizon=8, terminated=np.array([True, True])))
    assert default_costs("hopper") == ("x_velocity", "fall")
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
    assert default_costs("halfcheetah") == ("x_velocity",)
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
    from minsubdt_jax.scoring import Scoring, score_episodes

    obs = np.zeros((3, 10, 11))
    obs[:, :, 5] = np.array([3.0, 1.5, 3.0])[:, None]  # x cost (4 - v) / 5: 0.2, 0.5, 0.2 (the last falls at 5)
    lengths, fell = np.array([10, 10, 5]), np.array([False, False, True])
    demos = np.array([[0.5, 0.0], [0.4, 0.0]])  # mean [0.45, 0]: nobody fell
    ev = score_episodes("hopper", obs, lengths, np.ones((3, 10)), terminated=fell, horizon=10,
                        scoring=Scoring(demo_costs=demos))
    np.testing.assert_allclose(ev.costs, [[0.2, 0.0], [0.5, 0.0], [0.6, 0.5]], rtol=1e-6)
    assert ev.beats_mean_demo.tolist() == [True, False, False]


def test_each_built_in_metric_per_step_on_hand_made_steps():
    """Walker layout (obs 17: qpos[1:] 8, then qvel 9: v_x at 8, v_z at 9, the joints' velocities 11..16)."""
    obs, act = np.zeros((1, 2, 17), np.float32), np.zeros((1, 2, 6), np.float32)
    obs[0, :, 8] = [2.5, 7.0]      # v_x
    obs[0, :, 9] = [-1.5, 4.0]     # v_z
    obs[0, :, 1] = [-0.25, 2.0]    # torso pitch
    obs[0, 0, 11:] = [1, -2, 3, -4, 5, -6]
    obs[0, 1, 11:] = 20.0
    act[0, 0] = [1, -1, 0.5, 0, 0, 0]  # mean a^2 = 2.25 / 6
    per = lambda name: np.asarray(metric("walker", name).per_step(jnp.asarray(obs), jnp.asarray(act)))[0]  # noqa
    np.testing.assert_allclose(per("x_velocity"), [(6 - 2.5) / 7, 0.0], rtol=1e-6)
    np.testing.assert_allclose(per("fall"), [0.0, 0.0])
    np.testing.assert_allclose(per("energy"), [2.25 / 6, 0.0], rtol=1e-6)
    np.testing.assert_allclose(per("height_steadiness"), [0.5, 1.0], rtol=1e-6)
    np.testing.assert_allclose(per("uprightness"), [0.25, 1.0], rtol=1e-6)
    np.testing.assert_allclose(per("joint_speed"), [3.5 / 10, 1.0], rtol=1e-6)
    np.testing.assert_allclose(per("speed_band"), [0.0, (7 - 3.5) / 2 if 3.5 / 2 < 1 else 1.0], rtol=1e-6)
    np.testing.assert_allclose(per("speed_band:3:4"), [0.25, 1.0], rtol=1e-6)
    assert metric("walker", "speed_band:3:4").name == "speed_band:3:4"


def test_costs_choose_the_columns_and_their_order_and_bad_names_are_refused():
    rng = np.random.default_rng(2)
    obs, act = rng.normal(1, 1, (5, 30, 11)), rng.uniform(-1, 1, (5, 30, 3))
    lengths, fell = np.array([30, 12, 30, 5, 20]), np.array([False, True, False, True, False])
    cols = {n: np.asarray(engineered_costs("hopper", obs, lengths, 30, terminated=fell, actions=act, costs=n))[:, 0]
            for n in ("energy", "x_velocity", "uprightness")}
    f = np.asarray(engineered_costs("hopper", obs, lengths, 30, terminated=fell, actions=act,
                                    costs="energy,x_velocity,uprightness"))
    np.testing.assert_allclose(f, np.stack([cols["energy"], cols["x_velocity"], cols["uprightness"]], 1), rtol=1e-6)
    # a fall is charged 1 per step not lived on every metric, energy too
    assert f[3, 0] >= 25 / 30
    for bad, msg in (("x_velocity,speed", "unknown cost metric 'speed'"), ("energy,energy", "distinct"),
                     ("speed_band:1", "two parameters"), ("energy:2", "only speed_band")):
        with pytest.raises(ValueError, match=msg):
            cost_metrics("hopper", bad)
    with pytest.raises(ValueError, match="never falls"):
        cost_metrics("halfcheetah", "fall")
    with pytest.raises(ValueError, match="need the actions"):
        engineered_costs("hopper", obs, lengths, 30, terminated=fell, costs="energy")


def test_default_sets_reproduce_the_previous_features_bit_for_bit(small_dataset):
    """The features before the registry (costs.py at 9309806: one clip per velocity column, the fall column 0,
    horizon average with charge 1), inlined, against the default set on real data."""
    d = small_dataset

    def before(obs, lengths, horizon, terminated, index, lo, hi, fall):
        v = jnp.asarray(obs)[..., [index]]
        per = (jnp.asarray([hi]) - jnp.clip(v, jnp.asarray([lo]), jnp.asarray([hi]))) / (jnp.asarray([hi]) - jnp.asarray([lo]))
        if fall:
            per = jnp.concatenate([per, jnp.zeros_like(per[..., :1])], axis=-1)
        valid = (jnp.arange(per.shape[1])[None, :] < lengths[:, None])[..., None]
        lived = jnp.sum(jnp.where(valid, per, 0.0), axis=1)
        L = lengths[:, None].astype(per.dtype)
        return jnp.where(jnp.asarray(terminated)[:, None], (lived + horizon - L) / horizon, lived / jnp.maximum(L, 1.0))

    now = np.asarray(engineered_costs("hopper", d.observations, d.lengths, 60, terminated=d.terminals))
    np.testing.assert_array_equal(now, np.asarray(before(d.observations, jnp.asarray(d.lengths), 60, d.terminals,
                                                         5, -1.0, 4.0, True)))
    obs = np.random.default_rng(3).normal(3, 4, (6, 50, 17)).astype(np.float32)
    now = np.asarray(engineered_costs("halfcheetah", obs, np.full(6, 50), 50, terminated=np.zeros(6, bool)))
    np.testing.assert_array_equal(now, np.asarray(before(obs, jnp.full(6, 50), 50, np.zeros(6, bool), 8, -1.0, 15.0,
                                                         False)))


def test_a_metric_of_ones_own_changes_min_subdominance_as_computed_by_hand():
    """A user metric 'lean' (torso pitch p, range [-1, 1], lower is better: cost (p + 1) / 2) beside x_velocity.
    Demos a, b and rollouts r1, r2, never fell; features (x, lean): a (0.5, 0.25), b (0.25, 0.75), r1 (0.5, 0.5),
    r2 (0.5, 0.1). Eq. 2 with beta 1 separates per metric: g_k = min_{alpha >= 0} mean_j max(0, 1 + alpha (r_k -
    d_jk)). x for both rollouts: terms 1 and 1 + 0.25 alpha -> 1 at alpha = 0. lean for r1: 1 + 0.25 alpha and
    max(0, 1 - 0.25 alpha) average to 1 up to alpha = 4, more beyond -> 1; total 2. lean for r2 (below both
    demos): max(0, 1 - 0.15 alpha), max(0, 1 - 0.65 alpha) -> 0 from alpha = 1 / 0.15; total 1. Without lean,
    both are 1."""
    from minsubdt_jax.subdominance import min_subdominance

    lean = CostMetric("lean", lambda o, a: o[..., 1], -1.0, 1.0, meaning="torso pitch")
    ms = cost_metrics("walker", ["x_velocity", lean])
    assert [m.name for m in ms] == ["x_velocity", "lean"]
    obs = np.zeros((4, 2, 17), np.float32)
    obs[:, :, 8] = np.array([2.5, 4.25, 2.5, 2.5])[:, None]      # x cost (6 - v) / 7: 0.5, 0.25, 0.5, 0.5
    obs[:, :, 1] = np.array([-0.5, 0.5, 0.0, -0.8])[:, None]     # lean cost (p + 1) / 2: 0.25, 0.75, 0.5, 0.1
    F = np.asarray(trajectory_costs(ms, obs, np.full(4, 2), 2, terminated=np.zeros(4, bool)))
    np.testing.assert_allclose(F, [[0.5, 0.25], [0.25, 0.75], [0.5, 0.5], [0.5, 0.1]], rtol=1e-6)
    got = np.asarray(min_subdominance(F[2:], F[:2], 1.0).value)
    x_only = np.asarray(min_subdominance(F[2:, :1], F[:2, :1], 1.0).value)
    np.testing.assert_allclose(got, [2.0, 1.0], atol=1e-4)
    np.testing.assert_allclose(x_only, [1.0, 1.0], atol=1e-4)


def test_a_metric_of_ones_own_reaches_the_training_data_and_its_report(small_dataset_path):
    """The README's example, through the pipeline: a user's 'lean' beside the built-ins becomes the demos' third
    cost column (equal to its hand formula), min-subdominance and the surrogate return tokens use all three, and
    the dataset report names it; an unknown name is refused by train() before anything is read."""
    import dataclasses

    from minsubdt_jax.config import PRESETS, validate
    from minsubdt_jax.methods import get_method
    from minsubdt_jax.pipeline import prepare
    from minsubdt_jax.subdominance import min_subdominance
    from minsubdt_jax.train import train

    lean = CostMetric("lean", lambda obs, act: abs(obs[..., 1]), lo=0.0, hi=0.5)
    cfg = validate(dataclasses.replace(PRESETS["smoke"], env="hopper", dataset=small_dataset_path, episode_length=60))
    prep = prepare(cfg, get_method("minsubdt"), verbose=False, metrics=["x_velocity", "fall", lean])
    d = prep.source.data
    per = np.clip(np.abs(d.observations[..., 1]), 0, 0.5) / 0.5
    valid = np.arange(d.observations.shape[1])[None] < d.lengths[:, None]
    lived = np.where(valid, per, 0).sum(1)
    hand = np.where(d.terminals, (lived + 60 - d.lengths) / 60, lived / d.lengths)
    np.testing.assert_allclose(prep.costs[:, 2], hand, rtol=1e-5)
    np.testing.assert_allclose(prep.min_subdominance, np.asarray(min_subdominance(
        prep.costs, prep.costs, 1.0, leave_one_out=True).value), rtol=1e-6)
    assert [m["name"] for m in prep.summary("hopper")["cost_metrics"]] == ["x_velocity", "fall", "lean"]
    with pytest.raises(ValueError, match="unknown cost metric 'speed'"):
        train(cfg, metrics=["speed"], verbose=False)


def test_a_metric_at_lived_is_averaged_over_the_steps_lived_and_never_charges_a_fall():
    """Issue 55: with every unlived step charged 1, `energy` mostly measured survival. `energy@lived` averages the
    per-step cost over the steps lived, fallen or not (a fall is `fall`'s business); hand values: a 2-step episode
    that fell with actions a^2 = 0.25 and 0.75, and a 4-step one cut off with a^2 = 0.5."""
    obs = np.zeros((2, 4, 11))
    act = np.zeros((2, 4, 3))
    act[0, 0], act[0, 1], act[1] = 0.5, np.sqrt(0.75), np.sqrt(0.5)
    ms = cost_metrics("hopper", "energy,energy@lived,fall")
    assert [m.name for m in ms] == ["energy", "energy@lived", "fall"] and ms[1].not_lived is None
    f = np.asarray(trajectory_costs(ms, obs, np.array([2, 4]), horizon=8, terminated=np.array([True, False]),
                                    actions=act))
    np.testing.assert_allclose(f, [[(0.25 + 0.75 + 6) / 8, (0.25 + 0.75) / 2, 6 / 8], [0.5, 0.5, 0.0]], rtol=1e-6)
    for bad in ("fall@lived", "energy@horizon"):
        with pytest.raises(ValueError, match="the only suffix is @lived"):
            cost_metrics("hopper", bad)
    assert metric("walker", "speed_band:2:3@lived").name == "speed_band:2:3@lived"
