"""Behaviour policies at trade-offs between speed and energy (issue 74): the SAC reward with ``--energy-weight``,
the objectives, PEDA's amateur actions, the family's export and the ``mo-*`` recordings' preference labels."""

import json
import os
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from minsubdt_jax.behavior import tradeoffs
from minsubdt_jax.behavior.config import SACConfig
from minsubdt_jax.behavior.networks import amateur_policy_step, policy_step
from minsubdt_jax.behavior.snapshots import POLICY_DIR, load_manifest
from minsubdt_jax.behavior.train import SAC
from minsubdt_jax.envs import Rollout

TINY = dict(env="hopper", num_envs=4, batch_size=16, hidden=32, buffer_size=400, min_replay=100, chunk_steps=100,
            eval_every=100)


@struct.dataclass
class _State:  # a stand-in env's state: what SAC's env step reads
    obs: jax.Array
    reward: jax.Array
    done: jax.Array


class _Env:
    """A stand-in for the MJX env (no physics to compile): every step pays 2 and never ends."""

    def reset(self, rng):
        return _State(obs=jnp.zeros(11), reward=jnp.zeros(()), done=jnp.zeros(()))

    def step(self, state, action):
        return _State(obs=state.obs + 1.0, reward=jnp.asarray(2.0), done=jnp.zeros(()))


def test_energy_weight_swaps_the_control_cost(monkeypatch):
    """A stored reward is the env's with its control cost (hopper: 1e-3 |a|^2) replaced by lambda |a|^2."""
    from minsubdt_jax.behavior import train

    monkeypatch.setattr(train, "_RESETS", {})  # the stand-in's reset is no other test's
    for lam in (None, 0.5):
        sac = SAC(SACConfig(energy_weight=lam, **TINY))
        sac.env = _Env()
        state, env_state = sac.init(jax.random.PRNGKey(0))
        state, _, _ = sac.env_step(state, env_state, jnp.asarray(False))  # the actor's actions
        sq = np.square(np.asarray(state.buffer.action[:4])).sum(-1)
        want = 2.0 + (0.0 if lam is None else (1e-3 - lam) * sq)
        np.testing.assert_allclose(np.asarray(state.buffer.reward[:4]), want, rtol=1e-5)
        assert np.all(sq > 0)
    with pytest.raises(ValueError, match="--energy-weight"):
        SAC(SACConfig(energy_weight=-1.0, **TINY))


def test_objectives_and_preference_by_hand():
    obs = np.zeros((2, 3, 11), np.float32)
    obs[0, :, 5] = [1.0, 2.0, 0.0]  # hopper's x velocity (obs[5]); the third step is padding (length 2)
    obs[1, :, 5] = [-1.0, 0.5, 0.5]
    act = np.zeros((2, 3, 3), np.float32)
    act[0, 0] = [1.0, 0.0, 0.5]
    act[1, 2] = [0.0, 0.2, 0.0]
    z = np.zeros((2, 3))
    ro = Rollout(obs, act, z, np.array([2, 3]), np.array([False, False]), z, z)
    speed, energy = tradeoffs.objectives("hopper", ro)
    np.testing.assert_allclose(speed, [3.0, 0.0])
    np.testing.assert_allclose(energy, [1.25, 0.04], rtol=1e-6)
    np.testing.assert_allclose(tradeoffs.preference(0.25), [0.8, 0.2])


def test_amateur_scales_the_actors_action():
    """PEDA's amateur: with probability 0.65 the action times a factor in [0.35, 1.65], else the action itself."""
    params = _actor(0)
    obs = jnp.full((11,), 0.1)
    keys = jax.random.split(jax.random.PRNGKey(0), 400)
    a = jax.vmap(lambda k: amateur_policy_step(params, (), obs, 0.0, 0, k)[1])(keys)
    b = jax.vmap(lambda k: policy_step(params, (), obs, 0.0, 0, jax.random.split(k, 3)[0])[1])(keys)
    r = np.asarray(a) / np.asarray(b)
    np.testing.assert_allclose(r, r[:, :1] * np.ones_like(r), rtol=1e-4)  # one factor for the whole action
    ratios = r[:, 0]
    scaled = ~np.isclose(ratios, 1.0)
    assert 0.55 < scaled.mean() < 0.75 and ratios.min() >= 0.35 - 1e-4 and ratios.max() <= 1.65 + 1e-4


def _actor(k):
    from minsubdt_jax.behavior.snapshots import load_policy

    return load_policy("hopper", ("medium", "expert")[k])


def _fake_run(root, lam, role, objective):
    """A trade-off run directory whose snapshots are committed hopper policies (``role``: the better objective)."""
    run = os.path.join(root, f"l{lam}")
    os.makedirs(os.path.join(run, "snapshots"))
    snaps = []
    for i, (r, obj) in enumerate([("medium" if role == "expert" else "expert", objective - 1), (role, objective)]):
        name = f"step_{i + 1:08d}.npz"
        shutil.copy(os.path.join(POLICY_DIR, "hopper", load_manifest("hopper")[r]["snapshot"]),
                    os.path.join(run, "snapshots", name))
        snaps.append({"step": i + 1, "snapshot": name, "objective_mean": obj})
    with open(os.path.join(run, "config.json"), "w") as f:
        json.dump({"env": "hopper", "energy_weight": lam, "steps": 2}, f)
    with open(os.path.join(run, "snapshots.jsonl"), "w") as f:
        f.write("".join(json.dumps(s) + "\n" for s in snaps))
    return run


def test_export_and_mo_recording_label_each_policy(tmp_path, monkeypatch):
    from minsubdt_jax.data.named import generate

    monkeypatch.setattr(tradeoffs, "POLICY_DIR", str(tmp_path / "policies"))
    with pytest.raises(ValueError, match="no trade-off behaviour policies"):
        tradeoffs.load_manifest("hopper")
    runs = [_fake_run(str(tmp_path), 0.5, "medium", 3.0), _fake_run(str(tmp_path), 0.1, "expert", 9.0)]
    m = tradeoffs.export("hopper", runs, episodes=4, physics="mujoco", verbose=False)
    assert [p["energy_weight"] for p in m["policies"]] == [0.1, 0.5]  # lowest weight first
    assert [p["step"] for p in m["policies"]] == [2, 2]  # each run's best objective
    assert m["policies"][0]["measured"]["speed_mean"] > m["policies"][1]["measured"]["speed_mean"]  # expert runs on
    assert os.path.exists(tmp_path / "policies" / "hopper" / "tradeoffs" / "lambda0.1.npz")
    data, infos = generate("hopper", "mo-amateur", transitions=300, horizon=60, verbose=False, physics="mujoco")
    pref = infos["preference"]
    assert pref.shape == (data.num_transitions, 2) and data.num_transitions >= 300
    first = int(np.sum(data.lengths[:np.searchsorted(np.cumsum(data.lengths), 150) + 1]))  # the first policy's part
    np.testing.assert_allclose(pref[:first], np.tile(tradeoffs.preference(0.1), (first, 1)), rtol=1e-6)
    np.testing.assert_allclose(pref[first:], np.tile(tradeoffs.preference(0.5), (len(pref) - first, 1)), rtol=1e-6)
    grown = tradeoffs.export("hopper", [_fake_run(str(tmp_path), 0.3, "expert", 5.0)], episodes=4, physics="mujoco",
                             verbose=False)  # a family grows run by run: the others are kept
    assert [p["energy_weight"] for p in grown["policies"]] == [0.1, 0.3, 0.5]
    assert grown["policies"][0] == m["policies"][0]
    with open(os.path.join(runs[0], "config.json"), "w") as f:
        json.dump({"env": "hopper", "steps": 2}, f)
    with pytest.raises(ValueError, match="not a hopper trade-off run"):
        tradeoffs.export("hopper", runs, episodes=4, physics="mujoco", verbose=False)
