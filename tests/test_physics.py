"""The two physics backends and the two dynamics against independent references: brax's own MJX env, MJX against
C MuJoCo on the same model, gymnasium's own v4 envs, and the replay check that tells dynamics apart."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from minsubdt_jax.data.dataset import from_padded
from minsubdt_jax.envs import check_dynamics, dynamics_report, env_spec, make_rollout, random_policy, resolve_physics

GYM_IDS = {"hopper": "Hopper-{}", "walker": "Walker2d-{}", "halfcheetah": "HalfCheetah-{}"}
GYM_VERSIONS = {"d4rl": "v4", "v5": "v5"}  # the gymnasium env each of our dynamics reproduces


@functools.lru_cache(maxsize=None)
def _random_rollout(env, physics, dynamics="brax", episodes=16, horizon=200, seed=0):
    """One rollout of random actions, computed once per process (two tests read the MJX hopper one)."""
    run = make_rollout(env, random_policy, episodes, horizon, physics=physics, dynamics=dynamics)
    return jax.device_get(run(jnp.zeros(env_spec(env).act_dim), (), jax.random.PRNGKey(seed)))


@pytest.mark.slow
def test_mjx_env_steps_as_brax_own_env():
    """Our rules on MJX (brax dynamics) are brax's hopper, step for step: brax's own env reset from the keys our
    rollout drew its resets from, then stepped with the actions our rollout recorded, gives our observations,
    rewards and terminations (40 steps of 16 episodes)."""
    from brax import envs as brax_envs

    ours, theirs = _random_rollout("hopper", "mjx"), brax_envs.get_environment("hopper", backend="mjx")
    _, reset_rng = jax.random.split(jax.random.PRNGKey(0))  # as the rollout splits its key
    state = jax.jit(jax.vmap(theirs.reset))(jax.random.split(reset_rng, len(ours.lengths)))
    step = jax.jit(jax.vmap(theirs.step))
    for t in range(40):
        alive = ours.lengths > t  # our rollout records zeros after an episode ends, brax steps on: compare the alive
        np.testing.assert_allclose(ours.observations[alive, t], state.obs[alive], rtol=0, atol=1e-6 if t else 0)
        state = step(state, jnp.asarray(ours.actions[:, t]))
        np.testing.assert_allclose(ours.rewards[alive, t], state.reward[alive], rtol=1e-6, atol=1e-6)
        ended = (ours.lengths == t + 1) & ours.terminated
        np.testing.assert_array_equal(np.asarray(state.done)[alive] > 0, ended[alive], err_msg=str(t))
    assert (ours.lengths > 40).any()


@pytest.mark.slow
@pytest.mark.parametrize("env, dynamics", [("hopper", "brax"), ("walker", "brax"), ("hopper", "d4rl"), ("walker", "v5")])
def test_c_mujoco_and_mjx_roll_out_the_same_episodes(env, dynamics):
    """Same model, same resets, same actions (the backends draw both from the same keys): 200 steps of random
    actions end at the same steps, with returns within 1e-3 relative and identical reset observations. The d4rl
    case is MJX on gym's XML (RK4, 100 solver iterations): the path a D4RL file takes on an accelerator; walker's v5
    case, on v5's own XML, Minari's (hopper's v5 is d4rl's model: its terminal reward is the same code on both)."""
    size = dict(episodes=8, horizon=100) if dynamics == "v5" else {}  # gym's walker XML in MJX: the costliest
    mjx, c = _random_rollout(env, "mjx", dynamics, **size), _random_rollout(env, "mujoco", dynamics, **size)
    np.testing.assert_array_equal(c.lengths, mjx.lengths)
    np.testing.assert_array_equal(c.terminated, mjx.terminated)
    np.testing.assert_allclose(c.observations[:, 0], mjx.observations[:, 0], rtol=0, atol=1e-6)
    r_c, r_m = c.rewards.sum(1), mjx.rewards.sum(1)
    np.testing.assert_allclose(r_c, r_m, rtol=1e-3, atol=1e-3 * np.abs(r_m).mean())
    np.testing.assert_allclose(c.actions, mjx.actions, rtol=0, atol=1e-6)  # the policy saw the same keys


@pytest.mark.slow
def test_halfcheetah_agrees_in_statistics():
    """halfcheetah is chaotic (two C runs 1e-7 apart separate after ~100 steps), so only the return distribution
    is compared: the means of 16 paired episodes differ by less than 4 standard errors."""
    mjx, c = _random_rollout("halfcheetah", "mjx"), _random_rollout("halfcheetah", "mujoco")
    assert (c.lengths == 200).all() and (mjx.lengths == 200).all() and not c.terminated.any()
    r_c, r_m = c.rewards.sum(1), mjx.rewards.sum(1)
    se = np.sqrt((r_c.var() + r_m.var()) / len(r_c))
    assert abs(r_c.mean() - r_m.mean()) < 4 * se, (r_c.mean(), r_m.mean(), se)
    np.testing.assert_allclose(c.rewards[:, :10], mjx.rewards[:, :10], rtol=1e-3, atol=1e-3)  # before chaos


@pytest.mark.parametrize("dynamics", ["d4rl", "v5"])
@pytest.mark.parametrize("env", ["hopper", "walker", "halfcheetah"])
def test_gym_dynamics_are_gymnasiums_own_envs(env, dynamics):
    """The d4rl and v5 rules on C MuJoCo against gymnasium's own ``Hopper``/``Walker2d``/``HalfCheetah`` ``-v4`` and
    ``-v5``: each recorded episode replayed in gymnasium from its recorded reset state with its recorded actions
    gives the same observations, rewards (v5: no healthy reward on the terminal step) and termination, over >= 200
    steps per env."""
    gym = pytest.importorskip("gymnasium")
    ro = _random_rollout(env, "mujoco", dynamics, episodes=16 if env != "halfcheetah" else 1, horizon=250)
    g = gym.make(GYM_IDS[env].format(GYM_VERSIONS[dynamics])).unwrapped
    g.reset(seed=0)
    steps = 0
    for i in range(len(ro.lengths)):
        g.reset(seed=i)
        g.set_state(ro.qpos[i, 0].astype(np.float64), ro.qvel[i, 0].astype(np.float64))
        for t in range(int(ro.lengths[i])):
            np.testing.assert_array_equal(ro.observations[i, t], g._get_obs().astype(np.float32))
            _, r, term, _, _ = g.step(ro.actions[i, t])
            np.testing.assert_allclose(ro.rewards[i, t], r, rtol=1e-6, atol=1e-6)
            last = t == ro.lengths[i] - 1
            assert term == (last and bool(ro.terminated[i])), (i, t)
            steps += 1
    assert steps >= 200


def test_check_dynamics_tells_brax_data_from_d4rl_data():
    """Episodes recorded under each dynamics, replayed from their recorded states: the dynamics that made them
    reproduces (nearly) every transition, the other almost none."""
    reports = {}
    for dyn in ("brax", "d4rl"):
        ro = _random_rollout("hopper", "mujoco", dyn, episodes=16, horizon=100, seed=1)
        data = from_padded(ro.observations, ro.actions, ro.rewards, ro.lengths, ro.terminated)
        mask = data.valid_mask()
        qpos, qvel = ro.qpos[:, :data.max_len][mask], ro.qvel[:, :data.max_len][mask]
        err = check_dynamics("hopper", data, qpos, qvel, transitions=300)
        other = "d4rl" if dyn == "brax" else "brax"
        assert err[dyn] < 1e-3 and err[other] > 100 * err[dyn], (dyn, err)
        reports[dyn] = dynamics_report("hopper", data, qpos, qvel, transitions=300)
        assert reports[dyn]["best"] == dyn and reports[dyn]["dynamics"][dyn]["reproduced"] == 1.0
        assert reports[dyn]["dynamics"][other]["reproduced"] < 0.5
    # the same states with other actions (data no env produced): neither reproduces it, and the report says so
    shuffled = from_padded(data.observations, np.roll(data.actions, 1, axis=0), data.rewards, data.lengths,
                           data.terminals)
    assert dynamics_report("hopper", shuffled, qpos, qvel, transitions=300)["best"] == "neither"


def test_physics_names_are_checked():
    """One clear error for an unknown physics or dynamics, and for C MuJoCo on a mesh of several devices."""
    with pytest.raises(ValueError, match="unknown physics 'bullet'"):
        resolve_physics("bullet")
    with pytest.raises(ValueError, match="unknown dynamics 'gym'"):
        make_rollout("hopper", random_policy, 2, 10, physics="mujoco", dynamics="gym")

    class TwoDevices:
        size = 2

    with pytest.raises(ValueError, match="--physics mujoco runs on one process's CPU cores"):
        resolve_physics("mujoco", TwoDevices())
    assert resolve_physics("auto", TwoDevices()) == "mjx" and resolve_physics("auto") == "mujoco"  # on this CPU


def test_a_gymnasium_v4_file_trains_and_is_evaluated_in_d4rl_dynamics(tmp_path):
    """A D4RL-layout file recorded by gymnasium's own Hopper-v4 (none of our attributes): its recorded states
    replay under the d4rl dynamics, so the run evaluates there and normalises with D4RL's references."""
    import dataclasses

    from minsubdt_jax.config import PRESETS, validate
    from minsubdt_jax.references import reference_returns
    from minsubdt_jax.train import train

    pytest.importorskip("gymnasium")
    import gymnasium_dataset as mod  # experiments/ (pyproject's pythonpath)

    path = str(tmp_path / "hopper-v4-random.hdf5")
    mod.record("hopper", 32, path, policy="random", horizon=60)
    cfg = dataclasses.replace(PRESETS["smoke"], env="hopper", dataset=path, episode_length=60,
                              out=str(tmp_path / "run"))
    res = train(validate(cfg), verbose=False)
    assert res["physics"]["dynamics"] == "d4rl" and res["physics"]["physics"] == "mujoco"
    how = res["physics"]["dynamics_from"]
    assert how["how"].startswith("checked") and how["best"] == "d4rl"
    assert how["dynamics"]["d4rl"]["reproduced"] == 1.0 and how["dynamics"]["brax"]["reproduced"] < 0.5
    lo, hi = reference_returns("hopper", "d4rl")
    assert (res["references"]["random"], res["references"]["expert"]) == (lo, hi)
    ev = res["eval"]
    np.testing.assert_allclose(ev["normalized_score_mean"], np.mean(100 * (np.array(ev["returns"]) - lo) / (hi - lo)),
                               rtol=1e-6)


def test_check_dynamics_tells_gymnasium_v5_from_v4():
    """Hopper's v4 and v5 step the same states; only v5's terminal step lacks the healthy reward. Episodes recorded
    in each replay equally well in both, and the terminal rewards name the one that made them; walker's v5 feet
    (friction 1.9) set its states apart from v4's outright."""
    for dyn in ("d4rl", "v5"):
        ro = _random_rollout("hopper", "mujoco", dyn, episodes=16, horizon=100, seed=1)
        data = from_padded(ro.observations, ro.actions, ro.rewards, ro.lengths, ro.terminated)
        mask = data.valid_mask()
        rep = dynamics_report("hopper", data, ro.qpos[:, :data.max_len][mask], ro.qvel[:, :data.max_len][mask],
                              transitions=300)
        assert rep["best"] == dyn and rep["same_states"] == ["d4rl", "v5"], rep
        other = "v5" if dyn == "d4rl" else "d4rl"
        assert rep["dynamics"][dyn]["terminal_reward_error"] < 1e-4 < 0.9 < rep["dynamics"][other][
            "terminal_reward_error"], rep
    ro = _random_rollout("walker", "mujoco", "v5", episodes=16, horizon=100, seed=1)
    data = from_padded(ro.observations, ro.actions, ro.rewards, ro.lengths, ro.terminated)
    mask = data.valid_mask()
    rep = dynamics_report("walker", data, ro.qpos[:, :data.max_len][mask], ro.qvel[:, :data.max_len][mask],
                          transitions=300)
    assert rep["best"] == "v5" and "same_states" not in rep, rep
