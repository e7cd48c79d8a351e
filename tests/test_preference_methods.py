"""PEDA's preference-conditioned baselines (issue 74): MODT(P), MORvS(P) and BC(P) read each episode's preference
label with its states; trained on a small labelled recording and evaluated at a preference of one's choosing."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

COSTS = ["--costs", "x_velocity,energy@lived"]
LABELS = np.array([[0.9, 0.1], [0.2, 0.8]], np.float32)  # episodes alternate between two preferences


@pytest.fixture(scope="module")
def labelled_path(small_dataset, tmp_path_factory):
    from minsubdt_jax.data import save_d4rl

    per_episode = LABELS[np.arange(small_dataset.num_trajectories) % 2]
    per_step = np.repeat(per_episode, small_dataset.lengths, axis=0)
    path = tmp_path_factory.mktemp("mo") / "hopper-mo-small.hdf5"
    save_d4rl(small_dataset, path, {"preference": per_step}, env="hopper", dynamics="brax", physics="mujoco")
    return str(path)


def _train(path, method, out):
    from minsubdt_jax.train import main

    assert main(["--preset", "smoke", "--env", "hopper", "--episode-length", "60", "--dataset", path, "--method",
                 method, *COSTS, "--out", str(out)]) == 0
    return str(out)


@pytest.fixture(scope="module")
def runs(labelled_path, tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    return {m: _train(labelled_path, m, root / m) for m in ("bc-p", "morvs-p", "modt-p")}


def test_states_carry_their_episodes_preference(labelled_path, small_dataset):
    """The sampler's states end in the episode's label, unnormalised; the evaluation's preference is the labels'
    mean; data without labels is one error naming the datasets that have them."""
    from minsubdt_jax.config import Config
    from minsubdt_jax.methods import METHODS
    from minsubdt_jax.pipeline import prepare

    cfg = Config(env="hopper", dataset=labelled_path, preset="smoke", episode_length=60,
                 costs="x_velocity,energy@lived")
    prep = prepare(cfg, METHODS["bc-p"], verbose=False)
    states = np.asarray(prep.sampler.states)
    for i in range(4):
        n = small_dataset.lengths[i]
        np.testing.assert_allclose(states[i, :n, -2:], np.tile(LABELS[i % 2], (n, 1)))
    np.testing.assert_allclose(prep.preference, LABELS[np.arange(len(states)) % 2].mean(0), rtol=1e-5)
    with pytest.raises(ValueError, match="no infos/preference: record a multi-preference dataset"):
        prepare(dataclasses.replace(cfg, dataset=_unlabelled(small_dataset, labelled_path)), METHODS["bc-p"],
                verbose=False)


def _unlabelled(data, beside):
    from minsubdt_jax.data import save_d4rl

    path = beside.replace(".hdf5", "-nolabels.hdf5")
    save_d4rl(data, path, env="hopper", dynamics="brax", physics="mujoco")
    return path


def test_policies_read_state_preference_and_return_as_written(runs):
    """By hand: BC(P)'s MLP reads the normalised (state, preference), MORvS(P)'s also the target scaled; both equal
    ``load_policy``'s action at a preference of one's choosing."""
    from minsubdt_jax.agents.mlp.networks import MLPPolicy
    from minsubdt_jax.evaluate import load_policy, load_run

    obs = np.linspace(-0.5, 0.5, 11).astype(np.float32)
    for method, extra in (("bc-p", 0), ("morvs-p", 2)):
        run = load_run(runs[method])
        params = jax.tree.map(lambda x: x[0], run.params)  # the first (only) model
        p = run.per_model[0]
        assert params["params"]["MLP_0"]["Dense_0"]["kernel"].shape[0] == 11 + 2 + extra
        policy = load_policy(runs[method], preference="x_velocity=3,energy@lived=1")
        x = (np.concatenate([obs, [0.75, 0.25]]) - p.state_mean) / p.state_std
        if extra:
            x = np.concatenate([x, np.asarray(policy.target) / p.rtg_scale])
        want = MLPPolicy(3, run.cfg.mlp_hidden, run.cfg.mlp_layers).apply(params, jnp.asarray(x))
        np.testing.assert_allclose(policy(obs), np.asarray(want), rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(policy.preference, [0.75, 0.25])
        with pytest.raises(ValueError, match=r"shape \(11,\)"):
            policy(np.zeros(13, np.float32))


def test_evaluate_modt_p_at_a_preference(runs, capsys):
    """MODT(P) evaluated at a preference: the states carry it, the token is the data's episode's that serves it (its
    label nearest), both written in the evaluation."""
    import json
    import os

    from minsubdt_jax.evaluate import load_run, main
    from minsubdt_jax.targets import episode_tokens, preference_target

    assert main([runs["modt-p"], "--preference", "0.2,0.8", "--episodes", "3"]) == 0
    with open(os.path.join(runs["modt-p"], "evaluations", "modt-p", "pref-x_velocity=0.2,energy@lived=0.8.json")) as f:
        ev = json.load(f)
    prep = load_run(runs["modt-p"]).per_model[0]
    token, i = preference_target(episode_tokens(prep), np.array([0.2, 0.8]), prep.preference_labels)
    assert i % 2 == 1  # an episode labelled (0.2, 0.8)
    np.testing.assert_allclose(ev["eval"]["target_return"], token, rtol=1e-6)
    np.testing.assert_allclose(ev["eval"]["preference"], [0.2, 0.8], rtol=1e-6)
    with open(os.path.join(runs["modt-p"], "results.json")) as f:
        res = json.load(f)
    np.testing.assert_allclose(res["eval"]["preference"], prep.preference, rtol=1e-6)
    for w in ("1,0", "0,1"):  # a one-token method's evaluations at two preferences are two files
        assert main([runs["bc-p"], "--preference", w, "--episodes", "3"]) == 0
    assert sorted(os.listdir(os.path.join(runs["bc-p"], "evaluations", "bc-p"))) == [
        "pref-x_velocity=0,energy@lived=1.json", "pref-x_velocity=1,energy@lived=0.json"]
