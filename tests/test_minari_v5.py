"""Minari's MuJoCo datasets are recorded in gymnasium's v5 envs with their references in the metadata (issue 73): a
dataset made here the way Minari's were (``minari.DataCollector`` around ``Hopper-v5``) trains with no
``--dynamics``, is evaluated in our v5 rules, and is scored with its own references; an env we cannot serve is one
error line."""

import dataclasses

import numpy as np
import pytest

minari = pytest.importorskip("minari")
gym = pytest.importorskip("gymnasium")


def make_dataset(dataset_id: str, env_id: str = "Hopper-v5", episodes: int = 24, horizon: int = 60, **kwargs):
    """``episodes`` random-action episodes of ``env_id`` (``kwargs`` to ``gym.make``) through Minari's
    ``DataCollector``, with references in the metadata as Minari's own datasets have them."""
    env = minari.DataCollector(gym.make(env_id, max_episode_steps=horizon, **kwargs))
    env.action_space.seed(0)
    for i in range(episodes):
        env.reset(seed=i)
        while True:
            _, _, term, trunc, _ = env.step(env.action_space.sample())
            if term or trunc:
                break
    return env.create_dataset(dataset_id=dataset_id, algorithm_name="random", ref_min_score=-19.0,
                              ref_max_score=3500.0, eval_env=env_id, author="tests", description="random actions",
                              code_permalink="tests/test_minari_v5.py", author_email="tests@example.org")


def test_a_v5_minari_dataset_trains_and_scores_in_v5_with_its_own_references(tmp_path, monkeypatch):
    from minsubdt_jax.config import PRESETS, validate
    from minsubdt_jax.train import train

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    ds = make_dataset("test/hopper/tiny-v0")
    cfg = dataclasses.replace(PRESETS["smoke"], env="hopper", dataset="minari:test/hopper/tiny-v0",
                              episode_length=60, out=str(tmp_path / "run"))
    res = train(validate(cfg), verbose=False)
    assert res["physics"]["dynamics"] == "v5" and "env spec" in res["physics"]["dynamics_from"]["how"]
    refs = res["references"]
    assert (refs["random"], refs["expert"], refs["dynamics"]) == (-19.0, 3500.0, "v5")
    assert "ref_min_score" in refs["source"]
    ev = res["eval"]  # the rollouts' returns normalised with the dataset's references
    np.testing.assert_allclose(ev["normalized_score_mean"], np.mean(100 * (np.array(ev["returns"]) + 19.0) / 3519.0),
                               rtol=1e-6)
    returns = [float(np.sum(e.rewards)) for e in ds.iterate_episodes()]  # and the data's own score as Minari's
    np.testing.assert_allclose(res["dataset"]["normalized_score_mean"],
                               100 * np.mean(minari.get_normalized_score(ds, np.array(returns))), rtol=1e-5)


@pytest.mark.parametrize("env_id, kwargs, says", [("InvertedPendulum-v5", {}, "its env InvertedPendulum-v5"),
                                                  ("Hopper-v5", {"ctrl_cost_weight": 0.1},
                                                   "its env Hopper-v5 with {'ctrl_cost_weight': 0.1}")])
def test_a_minari_env_we_cannot_serve_is_one_error_line(tmp_path, monkeypatch, capsys, env_id, kwargs, says):
    from minsubdt_jax.train import main

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    make_dataset("test/odd/tiny-v0", env_id, episodes=3, horizon=20, **kwargs)
    out = tmp_path / "run"
    assert main(["--preset", "smoke", "--env", "hopper", "--episode-length", "60", "--dataset",
                 "minari:test/odd/tiny-v0", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: minari:test/odd/tiny-v0: ") and says in err and err.count("\n") == 1, err
    assert not out.exists()


def test_the_v5_cell_recording_is_a_v5_minari_dataset_with_references_measured_in_it(tmp_path, monkeypatch):
    """``experiments/gymnasium_dataset.py --version v5 --minari ID`` (the v5 cell's recording): the D4RL-layout file
    replays under v5 (not v4: the terminal rewards), and the Minari dataset loads as v5 data with the random and
    expert returns it measured as its references."""
    import gymnasium_dataset as mod  # experiments/ (pyproject's pythonpath)

    from minsubdt_jax.data import resolve_dataset
    from minsubdt_jax.data.d4rl import file_dynamics

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    out = mod.record("hopper", 12, str(tmp_path / "h.hdf5"), policy="random", horizon=60, version="v5")
    refs = mod.to_minari(out["rows"], "hopper", "v5", "test/hopper-v5/random-v0", 60, ref_episodes=2, seed=0)
    f = resolve_dataset("hopper", str(tmp_path / "h.hdf5"), verbose=False)
    dyn, how = file_dynamics(f, "hopper")
    assert dyn == "v5" and how["same_states"] == ["d4rl", "v5"], how
    m = resolve_dataset("hopper", "minari:test/hopper-v5/random-v0", verbose=False)
    assert m.dynamics == "v5" and m.references[:2] == (refs["random"], refs["expert"]) and m.sha256 == f.sha256
    assert refs["expert"] > 3 * abs(refs["random"])  # 60-step episodes: the expert hops, random actions fall
