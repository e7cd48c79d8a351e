"""Named datasets recorded from the committed behaviour policies (hopper: the cheapest env; C MuJoCo, auto)."""

import h5py
import numpy as np
import pytest

from minsubdt_jax.behavior.snapshots import load_manifest
from minsubdt_jax.data import generate, load_d4rl, resolve_dataset
from minsubdt_jax.data.__main__ import main as data_main
from minsubdt_jax.envs import env_spec
from minsubdt_jax.references import normalized_score, reference_returns

pytestmark = pytest.mark.slow
SMALL = dict(transitions=2000, horizon=1000)  # 8 parallel 1000-step episodes per rollout call
# random episodes fall within ~60 steps: 32 parallel episodes of at most 60 steps, the rollout program of the
# session's small dataset (conftest), compiled once
SIZES = {"random": dict(transitions=480, horizon=60), "medium": SMALL, "expert": SMALL}


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    mp.setenv("XDG_CACHE_HOME", str(tmp_path_factory.mktemp("xdg")))
    yield
    mp.undo()


@pytest.fixture(scope="module")
def recorded(cache):
    return {d: resolve_dataset("hopper", d, **SIZES[d], verbose=False) for d in SIZES}


def test_generation_is_deterministic_for_a_seed(recorded):
    medium = recorded["medium"].data
    again, _ = generate("hopper", "medium", **SMALL, seed=0, verbose=False)
    other, _ = generate("hopper", "medium", **SMALL, seed=1, verbose=False)
    for name in ("observations", "actions", "rewards", "lengths", "terminals"):
        np.testing.assert_array_equal(getattr(again, name), getattr(medium, name))
    assert not np.array_equal(other.returns, medium.returns)


def test_datasets_reach_the_requested_size_in_whole_episodes(recorded):
    for name, f in recorded.items():
        data, want, horizon = f.data, SIZES[name]["transitions"], SIZES[name]["horizon"]
        assert data.num_transitions >= want, name
        assert data.num_transitions - data.lengths[-1] < want, name  # the last episode crossed the target
        assert data.max_len <= horizon
        timeouts = ~data.terminals
        assert np.all(data.lengths[timeouts[:-1].nonzero()[0]] == horizon)  # time-outs are full-horizon episodes


def test_medium_is_between_random_and_expert(recorded):
    r = {d: recorded[d].data.returns.mean() for d in recorded}
    assert r["random"] < r["medium"] < r["expert"], r
    lo, hi = reference_returns("hopper")
    refs = load_manifest("hopper")["references"]
    assert refs["random"]["episodes"] >= 100 and refs["expert"]["episodes"] >= 100
    np.testing.assert_allclose(normalized_score("hopper", [lo, hi]), [0.0, 100.0])


def test_medium_expert_file_is_medium_and_expert_in_d4rl_layout(recorded):
    me = resolve_dataset("hopper", "medium-expert", **SMALL, verbose=False)
    data, path = me.data, me.path
    medium, expert = recorded["medium"].data, recorded["expert"].data
    assert data.num_trajectories == medium.num_trajectories + expert.num_trajectories
    # per-step rewards, exactly (returns are float32 sums, which may round differently over other padding)
    T = data.max_len
    pad = lambda r: np.pad(r, ((0, 0), (0, T - r.shape[1])))  # noqa: E731
    np.testing.assert_array_equal(data.rewards, np.concatenate([pad(medium.rewards), pad(expert.rewards)]))
    np.testing.assert_allclose(data.returns, np.concatenate([medium.returns, expert.returns]), rtol=1e-6)
    assert me.env == "hopper" and me.sha256 == load_d4rl(path).sha256() != recorded["medium"].sha256
    loaded = load_d4rl(path)
    np.testing.assert_array_equal(loaded.lengths, data.lengths)
    with h5py.File(path) as f:
        n = f["observations"].shape[0]
        assert n == data.num_transitions and f["terminals"].dtype == bool and f["timeouts"].dtype == bool
        assert f["infos/qpos"].shape == (n, 6) and f["infos/qvel"].shape == (n, 6)
        # independent check of the infos against gym's observation layout (brax follows it): torso height
        # (the torso's centre: rootz + 1.25 m, moved by the torso's tilt), qpos[2:], then qvel clipped to [-10, 10]
        obs, qpos, qvel = f["observations"][()], f["infos/qpos"][()], f["infos/qvel"][()]
        np.testing.assert_allclose(obs[:, 0], qpos[:, 1] + 1.25, atol=0.1)
        np.testing.assert_allclose(obs[:, 1:5], qpos[:, 2:], atol=1e-5)
        np.testing.assert_allclose(obs[:, 5:], np.clip(qvel, -10, 10), atol=1e-5)
        np.testing.assert_array_equal(f["infos/x_velocity"][()], qvel[:, 0])
        assert env_spec("hopper").x_velocity_index == 5


def test_cli_summary_and_bad_input(recorded, capsys):
    assert data_main(["--env", "hopper", "--dataset", "medium", "--transitions", "2000"]) == 0
    out = capsys.readouterr().out
    assert "hopper/medium:" in out and "normalised score" in out and "cached" in out
    assert data_main(["--env", "hopper", "--dataset", "medium", "--transitions", "0"]) == 2
    assert "transitions and horizon must be >= 1" in capsys.readouterr().err
    # --check-dynamics on our own recording: replayed from its infos/qpos, qvel, the brax dynamics reproduce it
    assert data_main(["--env", "hopper", "--dataset", recorded["medium"].path, "--check-dynamics"]) == 0
    out = capsys.readouterr().out
    assert "the data came from the brax dynamics (the file says brax)" in out
    with pytest.raises(SystemExit) as e:  # argparse: usage and exit 2
        data_main(["--env", "hopper", "--dataset", "medium", "--physics", "bullet"])
    assert e.value.code == 2 and "invalid choice: 'bullet'" in capsys.readouterr().err


def test_medium_replay_weights_stand_for_the_replay_buffer():
    """D4RL's medium-replay is SAC's replay buffer up to the medium checkpoint: the random warm-up holds
    ``min_replay`` steps, every later step the nearest snapshot's policy, and the steps add up to medium's."""
    from minsubdt_jax.behavior.snapshots import replay_weights

    for env in ("hopper", "walker", "halfcheetah"):
        m = load_manifest(env)
        w = replay_weights(env)
        steps = [r["step"] for r in m["replay"]]
        assert len(w) == 1 + len(steps) and all(x > 0 for x in w)
        assert w[0] == m["training"]["config"]["min_replay"] and sum(w) == m["medium"]["step"] == steps[-1]
    # hopper's snapshots at 10k, 30k, ..., 160k: boundaries at the midpoints (20k, 40k, 60k, 85k, 110k, ...)
    assert replay_weights("hopper") == [10000, 10000, 20000, 20000, 25000, 25000, 20000, 20000, 10000]


def test_minari_export_loads_in_minari_and_trains_back(recorded, tmp_path, monkeypatch, capsys):
    """--export-minari writes a local Minari dataset: minari loads the same episodes and returns with T+1
    observations, the final one computed by replaying the last action from the recorded last state, which on
    episodes cut one step short reproduces the recorded observation; the metadata holds our references and the
    file's hash; its env spec makes our env as a gymnasium env, which replays a recorded episode; --dataset
    minari:ID loads the same data (same hash) and trains; a taken ID or a missing one is one error."""
    import minari

    from minsubdt_jax.config import PRESETS
    from minsubdt_jax.data.d4rl import read_infos
    from minsubdt_jax.data.dataset import from_padded
    from minsubdt_jax.envs.check import final_observations
    from minsubdt_jax.train import train

    f = recorded["medium"]
    d, infos = f.data, read_infos(f.path)
    # the last step of every episode taken off: its "final observation" must be the recorded one
    short = from_padded(d.observations, d.actions, d.rewards, d.lengths - 1, np.zeros(d.num_trajectories, bool))
    keep = np.concatenate([np.arange(s, s + L - 1) for s, L in zip(np.cumsum(d.lengths) - d.lengths, d.lengths)])
    got = final_observations("hopper", "brax", short, infos["qpos"][keep], infos["qvel"][keep])
    np.testing.assert_allclose(got, d.observations[np.arange(d.num_trajectories), d.lengths - 1], atol=1e-4)

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    args = ["--env", "hopper", "--dataset", f.path, "--export-minari", "test/hopper-medium-v0"]
    assert data_main(args) == 0 and "--dataset minari:test/hopper-medium-v0" in capsys.readouterr().out
    ds = minari.load_dataset("test/hopper-medium-v0")
    eps = list(ds.iterate_episodes())
    assert len(eps) == d.num_trajectories and ds.total_steps == d.num_transitions
    for i, e in enumerate(eps):
        L = d.lengths[i]
        assert e.observations.shape == (L + 1, 11) and bool(e.terminations[-1]) == bool(d.terminals[i])
        assert bool(e.truncations[-1]) != bool(d.terminals[i]) and not e.terminations[:-1].any()
        np.testing.assert_array_equal(e.observations[:L], d.observations[i, :L])
        assert np.sum(e.rewards) == pytest.approx(d.returns[i], rel=1e-5)
    meta = ds.storage.metadata
    lo, hi = reference_returns("hopper", "brax")
    assert (meta["ref_min_score"], meta["ref_max_score"]) == (pytest.approx(lo), pytest.approx(hi))
    assert meta["minsubdt_sha256"] == f.sha256 and meta["minsubdt_dynamics"] == "brax"
    assert 100 * minari.get_normalized_score(ds, d.returns[:1])[0] == pytest.approx(
        normalized_score("hopper", d.returns[:1])[0], rel=1e-5)
    env = ds.recover_environment()  # what d3rlpy's get_minari calls: our env as a gymnasium env
    assert env.spec.id == "minsubdt/Hopper-brax-v0" and env.observation_space == ds.observation_space
    u = env.unwrapped  # it steps as the recorder did: episode 0 replayed from its first recorded state
    env.reset(seed=0)
    u.sims.set_state(infos["qpos"][:1].astype(np.float64), infos["qvel"][:1].astype(np.float64))
    for t in range(d.lengths[0]):
        obs, r, term, trunc, _ = env.step(d.actions[0, t])
        assert r == pytest.approx(d.rewards[0, t], abs=1e-4) and term == (t == d.lengths[0] - 1 and d.terminals[0])
        if t + 1 < d.lengths[0]:
            np.testing.assert_allclose(obs, d.observations[0, t + 1], atol=1e-4)
    back = resolve_dataset("hopper", "minari:test/hopper-medium-v0", verbose=False)
    assert back.sha256 == f.sha256 and back.dynamics == "brax"
    import dataclasses

    res = train(dataclasses.replace(PRESETS["smoke"], env="hopper", dataset="minari:test/hopper-medium-v0",
                                    episode_length=1000, out=str(tmp_path / "run")), verbose=False)
    assert res["dataset"]["sha256"] == f.sha256 and np.isfinite(res["eval"]["normalized_score_mean"])
    assert data_main(args) == 2 and "exists already" in capsys.readouterr().err
    with pytest.raises(Exception, match="no local Minari dataset 'nope'"):
        resolve_dataset("hopper", "minari:nope", verbose=False)
