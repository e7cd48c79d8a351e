import h5py
import jax
import jax.numpy as jnp
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
    # the last 2 steps end neither way (an episode the recording stopped inside): dropped, as the DT loader does
    assert d.num_trajectories == 2 and d.lengths.tolist() == [4, 4]
    assert d.terminals.tolist() == [True, False]
    np.testing.assert_allclose(d.returns, [a["rewards"][:4].sum(), a["rewards"][4:8].sum()], rtol=1e-6)
    np.testing.assert_allclose(d.observations[1], a["observations"][4:8], rtol=1e-6)


def test_trailing_unfinished_episode_is_dropped_and_counted(tmp_path):
    from minsubdt_jax.data import open_d4rl

    _write(tmp_path / "t.hdf5", _flat())
    f = open_d4rl(tmp_path / "t.hdf5")
    assert f.dropped_transitions == 2 and f.data.num_transitions == 8
    a = _flat()
    a["terminals"][:] = False
    a["timeouts"][:] = False
    with pytest.raises(DatasetError, match="no episode ends"):
        from_flat(a)


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
    (lambda a: a.pop("actions"), r"missing keys \['actions'\]"),
    (lambda a: a.update(rewards=a["rewards"][:-1]), "mismatched lengths"),
    (lambda a: a["observations"].__setitem__((2, 1), np.nan), r"non-finite .* 'observations' .* first \[2\]"),
    (lambda a: a["actions"].__setitem__((5, 0), np.inf), r"non-finite .* 'actions'"),
    (lambda a: [a.__setitem__(k, v[:0]) for k, v in list(a.items())], "empty"),
    # finite in the file's float64, inf once in float32: refused, not trained on
    (lambda a: a["observations"].__setitem__((4, 0), 1e39), r"beyond ±3.4e38\) at 1 rows, first \[4\]"),
    # each reward fits float32, their sum over the episode does not
    (lambda a: a["rewards"].__setitem__(slice(0, 2), 3e38), r"returns of 1 episodes overflow"),
    (lambda a: a.update(terminals=np.where(np.arange(10) == 6, np.nan, a["terminals"].astype(float))),
     r"'terminals' must be 0/1 .* first \[6\]"),
    (lambda a: a.update(actions=np.array([[b"a", b"b"]] * 10)), "non-numeric arrays"),
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
    real = a["observations"][:8]  # the two episodes; the unfinished last one is dropped
    np.testing.assert_allclose(d.state_stats()[0], real.mean(0), rtol=1e-5)
    np.testing.assert_allclose(d.state_stats()[1], real.std(0), rtol=1e-5)


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
    # episodes of weight 0 (another dataset's, in a program over several) are never drawn and leave the draws of
    # the others as they were, shifted to their new rows
    from minsubdt_jax.data import draw_episodes

    key = jax.random.PRNGKey(3)
    alone = np.asarray(draw_episodes(key, jnp.array([1, 3, 6], jnp.int32), 500))
    among = np.asarray(draw_episodes(key, jnp.array([0, 0, 1, 0, 3, 6, 0], jnp.int32), 500))
    assert set(alone) == {0, 1, 2}
    np.testing.assert_array_equal(among, np.array([2, 4, 5])[alone])


def test_generated_dataset_is_deterministic_and_valid(small_dataset):
    from minsubdt_jax.data import generate_random

    again = generate_random("hopper", episodes=32, horizon=HORIZON, seed=0)
    np.testing.assert_array_equal(again.observations, small_dataset.observations)
    assert small_dataset.num_trajectories == 32 and small_dataset.lengths.max() <= HORIZON
    assert np.all(np.abs(small_dataset.actions) <= 1)
    # random hopper falls over: terminations are recorded apart from time-outs
    assert small_dataset.terminals.any()
    assert np.all(small_dataset.terminals | (small_dataset.lengths == HORIZON))


def test_v0_file_without_timeouts_infers_them_from_the_horizon(tmp_path):
    """D4RL v0 files have no ``timeouts``: episodes end on a termination or every ``horizon`` steps."""
    from minsubdt_jax.data import open_d4rl

    a = _flat(n=25)
    a["terminals"][:] = False
    a["terminals"][3] = True
    tout = np.zeros(25, bool)
    tout[[13, 23]] = True  # what a v1 file would flag with a time limit of 10 steps
    del a["timeouts"]
    _write(tmp_path / "v0.hdf5", a)
    f = open_d4rl(tmp_path / "v0.hdf5", horizon=10)
    assert f.timeouts_inferred and f.data.lengths.tolist() == [4, 10, 10] and f.dropped_transitions == 1
    assert f.data.terminals.tolist() == [True, False, False]
    explicit = from_flat({**a, "timeouts": tout})
    np.testing.assert_array_equal(f.data.observations, explicit.observations)
    assert not open_d4rl(_save_small(tmp_path)).timeouts_inferred


def _save_small(tmp_path, name="ours.hdf5", env="hopper"):
    path = tmp_path / name
    save_d4rl(from_flat(_flat(n=40)), path, infos={"x": np.arange(40.0)}, env=env)
    return path


def test_checksum_catches_changed_contents(tmp_path):
    from minsubdt_jax.data import open_d4rl, read_infos

    path = _save_small(tmp_path)
    f = open_d4rl(path)
    assert f.env == "hopper" and f.sha256 == f.data.sha256() and len(f.sha256) == 64
    with h5py.File(path, "r+") as h:
        h["actions"][5] = 0.0  # what HDF5 returns for a lost chunk
    with pytest.raises(DatasetError, match="damaged: its contents do not match the checksum"):
        load_d4rl(path)
    path = _save_small(tmp_path, "infos.hdf5")
    with h5py.File(path, "r+") as h:
        h["infos/x"][3] = 0.0
    load_d4rl(path)  # the episodes are intact
    with pytest.raises(DatasetError, match="infos do not match"):
        read_infos(path)


def test_zeroed_blocks_never_load_silently_wrong(tmp_path):
    """Zero each 4 KB block of a written file in turn (what a lost disk block does): every load either returns
    the very same data or fails with one DatasetError, never another exception or other data."""
    src = tmp_path / "src.hdf5"
    data = from_flat(_flat(n=3000, obs=11, act=3))
    save_d4rl(data, src)
    raw = src.read_bytes()
    outcomes = {"same": 0, "error": 0}
    for off in range(0, len(raw), 4096):
        bad = tmp_path / "bad.hdf5"
        bad.write_bytes(raw[:off] + bytes(min(4096, len(raw) - off)) + raw[off + 4096:])
        try:
            got = load_d4rl(bad)
        except DatasetError:
            outcomes["error"] += 1
            continue
        assert got.sha256() == data.sha256(), f"block at {off} changed the data without an error"
        outcomes["same"] += 1
    assert outcomes["error"] > 0 and sum(outcomes.values()) == -(-len(raw) // 4096), outcomes


def test_data_must_fit_the_env(tmp_path, small_dataset, small_dataset_path):
    """hopper data as walker (shapes), walker-like data as halfcheetah (same shapes, other reset state), and a
    file recorded in another env: each one DatasetError naming the likely env."""
    with pytest.raises(DatasetError, match="size 11 and actions of size 3; walker has 17 and 6.*fits hopper"):
        save_d4rl(small_dataset, tmp_path / "plain.hdf5")  # no env record: the shapes tell
        resolve_dataset("walker", str(tmp_path / "plain.hdf5"))
    with pytest.raises(DatasetError, match="recorded in hopper, not in walker"):
        resolve_dataset("walker", small_dataset_path)
    a = _flat(n=40, obs=17, act=6)
    a["observations"][:, 0] = 1.25  # a walker's torso height at reset (halfcheetah's obs[0] starts at 0)
    _write(tmp_path / "w.hdf5", a)
    assert resolve_dataset("walker", str(tmp_path / "w.hdf5")).data.obs_dim == 17
    with pytest.raises(DatasetError, match="a walker reset state .* is it a walker dataset"):
        resolve_dataset("halfcheetah", str(tmp_path / "w.hdf5"))
    path = _save_small(tmp_path, "rec.hdf5", env="halfcheetah")
    with pytest.raises(DatasetError, match="recorded in halfcheetah, not in hopper"):
        resolve_dataset("hopper", str(path))


RACE = """
import sys, time, numpy as np
from minsubdt_jax.data import named
from minsubdt_jax.data.dataset import from_padded

def slow_generate(env, dataset, transitions, horizon, seed, verbose, physics=None):
    with open(sys.argv[1], "a") as f:
        f.write("recorded\\n")
    rng = np.random.default_rng(seed)
    obs = rng.normal(size=(400, 50, 11)).astype(np.float32)
    obs[:, 0, 0] = 1.25
    time.sleep(1.0)  # long enough for the other process to arrive while this one records
    data = from_padded(obs, rng.uniform(-1, 1, (400, 50, 3)), rng.normal(size=(400, 50)), np.full(400, 50), np.zeros(400))
    return data, {"qpos": np.zeros((data.num_transitions, 6))}

named.generate = slow_generate
f = named.resolve_dataset("hopper", "medium", transitions=20000, horizon=50, verbose=False)
print(f.sha256, f.data.num_trajectories)
"""


def test_concurrent_recordings_of_one_dataset_record_it_once(tmp_path):
    """Two processes ask for the same uncached dataset at once: one records it, the other waits for the lock and
    loads the finished file; both get the same data and the cache holds one valid file."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, XDG_CACHE_HOME=str(tmp_path / "cache"), JAX_PLATFORMS="cpu")
    log = tmp_path / "log"
    procs = [subprocess.Popen([sys.executable, "-c", RACE, str(log)], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for _ in range(2)]
    outs = [p.communicate(timeout=300) for p in procs]
    for p, (o, e) in zip(procs, outs):
        assert p.returncode == 0, e[-3000:]
    assert outs[0][0] == outs[1][0] and outs[0][0].split()[1] == "400"
    assert log.read_text().count("recorded") == 1
    files = sorted(os.listdir(tmp_path / "cache" / "minsubdt_jax" / "datasets"))
    assert files == ["hopper-medium-t20000-h50-s0-mujoco.hdf5", "hopper-medium-t20000-h50-s0-mujoco.hdf5.lock"]
    assert load_d4rl(tmp_path / "cache" / "minsubdt_jax" / "datasets" / files[0]).sha256() == outs[0][0].split()[0]


def test_damaged_cache_file_names_the_file_and_force(tmp_path, monkeypatch):
    from minsubdt_jax.data.named import dataset_path

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    path = dataset_path("hopper", "medium", 2000, 60, 0)
    import os

    os.makedirs(os.path.dirname(path))
    with open(path, "wb") as f:
        f.write(b"\0" * 4096)
    with pytest.raises(DatasetError, match=r"hopper-medium-t2000-h60-s0-mujoco.hdf5: not a readable hdf5 file .* cached "
                                           r"recording: .*--dataset medium --force"):
        resolve_dataset("hopper", "medium", transitions=2000, horizon=60)
