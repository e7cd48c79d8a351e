"""A new environment from one file (issue 57): ``tests/swimmer_env.py``'s record, registered with
``envs.register_env``, steps as gymnasium's own ``Swimmer-v4`` does, records its ``random`` dataset, and trains and
evaluates at the smoke preset, with nothing else in the package told about it."""

import dataclasses

import numpy as np
import pytest


@pytest.fixture
def swimmer(request):
    from minsubdt_jax.envs import ENVS, register_env
    from swimmer_env import SWIMMER  # tests/ (beside this file)

    register_env(SWIMMER)
    request.addfinalizer(lambda: ENVS.pop("swimmer"))
    with pytest.raises(ValueError, match="exists already"):
        register_env(SWIMMER)
    return SWIMMER


def test_an_env_registered_after_the_gymnasium_envs_is_one_too(swimmer):
    """``envs.gym_env`` registered the envs known when it was imported, so a later one was no gymnasium env."""
    import gymnasium as gym

    from minsubdt_jax.envs.gym_env import IDS

    env = gym.make(IDS[("swimmer", "d4rl")])
    obs, _ = env.reset(seed=0)
    assert obs.shape == (8,) and env.step(np.zeros(2, np.float32))[0].shape == (8,)


def test_a_registered_env_steps_as_gymnasium_swimmer_v4(swimmer):
    """Our rules on C MuJoCo (a body in the floor's plane: x and y left out of the observation, no height), replayed
    in gymnasium's ``Swimmer-v4`` from each episode's reset state with its actions: the same observations and
    rewards, step by step."""
    gym = pytest.importorskip("gymnasium")
    from minsubdt_jax.envs import make_rollout, random_policy

    run = make_rollout("swimmer", random_policy, 4, 60, dynamics="d4rl", physics="mujoco")
    import jax

    ro = jax.tree.map(np.asarray, run(np.zeros(2, np.float32), (), jax.random.PRNGKey(0)))
    assert ro.observations.shape == (4, 60, 8) and (ro.lengths == 60).all() and not ro.terminated.any()
    g = gym.make("Swimmer-v4").unwrapped
    for i in range(4):
        g.reset(seed=i)
        g.set_state(ro.qpos[i, 0].astype(np.float64), ro.qvel[i, 0].astype(np.float64))
        for t in range(60):
            np.testing.assert_allclose(ro.observations[i, t], g._get_obs(), rtol=1e-5, atol=1e-5)
            _, r, term, _, _ = g.step(ro.actions[i, t])
            np.testing.assert_allclose(ro.rewards[i, t], r, rtol=1e-5, atol=1e-6)
            assert not term


def test_a_registered_env_records_its_random_dataset_trains_and_evaluates(swimmer, tmp_path, monkeypatch):
    """The named ``random`` dataset is recorded in the new env (8-entry observations, 2 actions), a MinSubDT run
    trains on it at the smoke preset with the env's default metric (x_velocity: it never falls), and its evaluation
    normalises with the record's own references."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    from minsubdt_jax.config import PRESETS, validate
    from minsubdt_jax.data import resolve_dataset
    from minsubdt_jax.train import train

    f = resolve_dataset("swimmer", "random", transitions=2000, horizon=100)
    assert f.data.observations.shape[-1] == 8 and f.data.actions.shape[-1] == 2 and (f.data.lengths == 100).all()
    cfg = dataclasses.replace(PRESETS["smoke"], env="swimmer", dataset="random", out=str(tmp_path / "run"))
    res = train(validate(cfg), verbose=False)
    lo, hi = swimmer.references["brax"][:2]
    assert res["references"]["random"] == lo and res["references"]["expert"] == hi
    ev = res["eval"]
    assert len(ev["returns"]) == cfg.eval_episodes
    np.testing.assert_allclose(ev["normalized_score_mean"], np.mean(100 * (np.array(ev["returns"]) - lo) / (hi - lo)),
                               rtol=1e-6)
