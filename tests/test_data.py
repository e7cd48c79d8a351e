import h5py
import jax
import numpy as np
import pytest

from minsubdt_jax.data import (
    DatasetError, from_flat, load_d4rl, resolve_dataset, sample_batch, sampler_data, save_d4rl)

from conftest import HORIZON


def _flat(n=10, obs=3, act=2):
    rng = np.random.default_rng(0)
    term = np.zeros(n, bool); term[3] = True
    tout = np.zeros(n, bool); tout[7] = True
    return {"observations": rng.normal(size=(n, obs)), "actions": rng.uniform(-1, 1, (n, act)),
            "rewards": rng.normal(size=n), "terminals": term, "timeouts": tout}


def test_from_flat_splits_on_terminals_and_timeouts():
    a = _flat()
    d = from_flat(a)
    assert d.num_trajectories == 3 and d.lengths.tolist() == [4, 4, 2]
    assert d.terminals.tolist() == [True, False, False]
    np.testing.assert_allclose(d.returns, [a["rewards"][:4].sum(), a["rewards"][4:8].sum(), a["rewards"][8:].sum()],
                               rtol=1e-6)
    np.testing.assert_allclose(d.observations[2, :2], a["observations"][8:], rtol=1e-6)
    assert np.all(d.observations[2, 2:] == 0)


def test_hdf5_round_trip(small_dataset, tmp_path):
    path = tmp_path / "d.hdf5"
    save_d4rl(small_dataset, path, infos={"marker": np.arange(small_dataset.num_transitions)})
    d = load_d4rl(path)
    assert d.num_trajectories == small_dataset.num_trajectories
    np.testing.assert_array_equal(d.lengths, small_dataset.lengths)
    np.testing.assert_array_equal(d.terminals, small_dataset.terminals)
    np.testing.assert_array_equal(d.observations, small_dataset.observations)
    np.testing.assert_array_equal(d.actions, small_dataset.actions)
    np.testing.assert_allclose(d.returns, small_dataset.returns, rtol=1e-6)
    with h5py.File(path) as f:
        assert sorted(f.keys()) == ["actions", "infos", "observations", "rewards", "terminals", "timeouts"]
        assert f["observations"].shape == (small_dataset.num_transitions, 11)
        # every episode ends with exactly one of terminal / timeout
        assert int(f["terminals"][()].sum() + f["timeouts"][()].sum()) == small_dataset.num_trajectories


def _write(path, arrays):
    with h5py.File(path, "w") as f:
        for k, v in arrays.items():
            f.create_dataset(k, data=v)


@pytest.mark.parametrize("mutate, message", [
    (lambda a: a.pop("timeouts"), r"missing keys \['timeouts'\]"),
    (lambda a: a.update(rewards=a["rewards"][:-1]), "mismatched lengths"),
    (lambda a: a["observations"].__setitem__((2, 1), np.nan), r"non-finite .* 'observations' .* first \[2\]"),
    (lambda a: a["actions"].__setitem__((5, 0), np.inf), r"non-finite .* 'actions'"),
    (lambda a: [a.__setitem__(k, v[:0]) for k, v in list(a.items())], "empty"),
])
def test_bad_files_give_one_clear_error(tmp_path, mutate, message):
    a = _flat()
    mutate(a)
    path = tmp_path / "bad.hdf5"
    _write(path, a)
    with pytest.raises(DatasetError, match=message):
        load_d4rl(path)


def test_missing_and_unreadable_files(tmp_path):
    with pytest.raises(DatasetError, match="no dataset file"):
        load_d4rl(tmp_path / "nope.hdf5")
    (tmp_path / "text.hdf5").write_text("not hdf5")
    with pytest.raises(DatasetError, match="not a readable hdf5"):
        load_d4rl(tmp_path / "text.hdf5")
    with pytest.raises(DatasetError, match="unknown dataset 'mediun'"):
        resolve_dataset("hopper", "mediun")


def test_state_stats_use_only_real_steps():
    d = from_flat(_flat())
    a = _flat()
    np.testing.assert_allclose(d.state_stats()[0], a["observations"].mean(0), rtol=1e-5)
    np.testing.assert_allclose(d.state_stats()[1], a["observations"].std(0), rtol=1e-5)


def test_sampler_windows_padding_and_weights():
    # three trajectories of lengths 1, 3, 6 whose observations encode (trajectory, time)
    lengths = [1, 3, 6]
    n, T = 3, 6
    obs = np.zeros((sum(lengths), 2)); k = 0
    for i, L in enumerate(lengths):
        for t in range(L):
            obs[k] = (i, t); k += 1
    term = np.zeros(sum(lengths), bool); term[np.cumsum(lengths) - 1] = True
    d = from_flat({"observations": obs, "actions": obs[:, :1] * 0 + 0.5, "rewards": np.ones(sum(lengths)),
                   "terminals": term, "timeouts": np.zeros_like(term)})
    rtg = np.arange(n * T, dtype=np.float32).reshape(n, T)
    data = sampler_data(d, rtg, np.zeros(2, np.float32), np.ones(2, np.float32))
    K, B = 4, 20000
    b = jax.device_get(sample_batch(jax.random.PRNGKey(0), data, B, K))
    traj = b.states[:, -1, 0].astype(int)  # the last token is always real
    # trajectories drawn in proportion to length: 1/10, 3/10, 6/10
    np.testing.assert_allclose(np.bincount(traj, minlength=3) / B, [0.1, 0.3, 0.6], atol=0.015)
    for i in range(0, B, 997):
        m = b.mask[i]
        n_real = int(m.sum())
        assert n_real >= 1 and np.all(m == (np.arange(K) >= K - n_real))  # left padding only
        t = b.states[i, m, 1].astype(int)
        assert np.all(np.diff(t) == 1) and np.all(b.timesteps[i, m] == t)  # consecutive real steps
        assert np.all(b.states[i, m, 0] == traj[i]) and np.all(b.returns_to_go[i, m] == rtg[traj[i], t])
        assert t[-1] < lengths[traj[i]] and (n_real == K or t[-1] == lengths[traj[i]] - 1)
        assert np.all(b.states[i, ~m] == 0) and np.all(b.actions[i, ~m] == 0) and np.all(b.returns_to_go[i, ~m] == 0)
    # start steps are uniform within a trajectory: for the length-6 one, windows start at each t w.p. 1/6
    six = traj == 2
    first_t = np.where(b.mask[six].all(1), b.states[six, 0, 1], -1)
    assert abs(np.mean(first_t == 0) - 1 / 6) < 0.03


def test_generated_dataset_is_deterministic_and_valid(small_dataset):
    from minsubdt_jax.data import generate_random

    again = generate_random("hopper", episodes=32, horizon=HORIZON, seed=0)
    np.testing.assert_array_equal(again.observations, small_dataset.observations)
    assert small_dataset.num_trajectories == 32 and small_dataset.lengths.max() <= HORIZON
    assert np.all(np.abs(small_dataset.actions) <= 1)
    # random hopper falls over: terminations are recorded apart from time-outs
    assert small_dataset.terminals.any()
    assert np.all(small_dataset.terminals | (small_dataset.lengths == HORIZON))
