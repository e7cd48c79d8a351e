"""SAC behaviour-policy trainer: networks and losses against direct formulas, and checkpoint resumption."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp
import pytest

from minsubdt_jax.behavior.losses import Transition, critic_loss
from minsubdt_jax.behavior.networks import Actor, DoubleCritic, sample_tanh_gaussian
from minsubdt_jax.behavior.snapshots import load_snapshot, save_snapshot
from minsubdt_jax.behavior.config import SACConfig
from minsubdt_jax.behavior.train import train
from minsubdt_jax.envs import MjxEnv


def test_tanh_gaussian_log_density_matches_direct_formula():
    mean = jnp.array([[0.3, -1.0, 0.0], [1.5, 0.2, -0.4]])
    log_std = jnp.array([[-1.0, 0.0, 0.5], [-0.5, -2.0, 0.1]])
    a, logp = sample_tanh_gaussian(mean, log_std, jax.random.PRNGKey(0))
    a64 = np.asarray(a, np.float64)
    u = np.arctanh(a64)
    m, s = np.asarray(mean, np.float64), np.exp(np.asarray(log_std, np.float64))
    ref = np.sum(-0.5 * ((u - m) / s) ** 2 - np.log(s) - 0.5 * np.log(2 * np.pi) - np.log(1 - a64 ** 2), axis=-1)
    np.testing.assert_allclose(np.asarray(logp), ref, rtol=1e-4, atol=1e-3)
    assert np.all(np.abs(a64) < 1)


def test_critic_loss_without_bootstrap_is_regression_on_reward():
    """With discount 0 the soft target is the reward: loss = 0.5 sum_i mean (Q_i(s, a) - r)^2."""
    actor, critic = Actor(2, (8, 8)), DoubleCritic((8, 8))
    k = jax.random.split(jax.random.PRNGKey(1), 6)
    obs, act = jax.random.normal(k[0], (5, 3)), jnp.tanh(jax.random.normal(k[1], (5, 2)))
    batch = Transition(obs=obs, action=act, reward=jax.random.normal(k[2], (5,)), discount=jnp.zeros(5),
                       next_obs=jax.random.normal(k[3], (5, 3)))
    ap, cp = actor.init(k[4], obs), critic.init(k[5], obs, act)
    loss = critic_loss(cp, cp, ap, jnp.log(0.2), batch, k[0], actor=actor, critic=critic, gamma=0.99)
    q = np.asarray(critic.apply(cp, obs, act))
    assert q.shape == (2, 5) and not np.allclose(q[0], q[1])  # two independent critics
    np.testing.assert_allclose(float(loss), 0.5 * np.sum(np.mean((q - np.asarray(batch.reward)) ** 2, axis=1)),
                               rtol=1e-5)


def test_snapshot_round_trip(tmp_path):
    params = Actor(3, (4, 4)).init(jax.random.PRNGKey(0), jnp.zeros((1, 5)))
    save_snapshot(str(tmp_path / "s.npz"), params, env="hopper", step=7, return_mean=1.5)
    loaded, meta = load_snapshot(str(tmp_path / "s.npz"))
    assert meta == {"env": "hopper", "step": 7, "return_mean": 1.5}
    jax.tree.map(np.testing.assert_array_equal, jax.device_get(params), loaded)


# hidden 256, 8 evaluation episodes of 1000 steps: the evaluation rollout is the very program that records a named
# dataset from a committed policy (tests/test_generate.py), compiled once per session (make_rollout is cached)
TINY = dict(env="hopper", num_envs=4, batch_size=16, hidden=256, buffer_size=400, min_replay=100, chunk_steps=100,
            eval_every=100, eval_episodes=8, episode_length=1000)


@pytest.mark.slow
def test_trainer_resumes_from_its_checkpoint(tmp_path, monkeypatch):
    """The SAC trainer runs on the agents' loop frame (``loop.chunk_loop``): a Ctrl-C stops it after the chunk under
    way and its checkpoint, with a resume command that finishes the run; a resumed run keeps its replay buffer."""
    from minsubdt_jax import loop
    from minsubdt_jax.behavior.config import parse_args
    from minsubdt_jax.rundir import Interrupted

    class Pressed:  # Ctrl-C pressed during the first chunk
        raised = True

        def restore(self):
            pass

    out = str(tmp_path / "sac")
    traced = []  # the envs' reset is traced once per process for the reset program, once in the chunk's, not at
    # every reset of a run and its resumptions
    reset = MjxEnv.reset
    monkeypatch.setattr(MjxEnv, "reset", lambda self, rng: traced.append(1) or reset(self, rng))
    with monkeypatch.context() as m:
        m.setattr(loop, "InterruptFlag", Pressed)
        stop = "at step 100 of 200; resume with: python -m minsubdt_jax.behavior.train"
        with pytest.raises(Interrupted, match=stop) as e:
            train(SACConfig(steps=200, out=out, **TINY), verbose=False)
    cfg, resume = parse_args(str(e.value).split("resume with: python -m minsubdt_jax.behavior.train ")[1].split())
    assert cfg == SACConfig(steps=200, out=out, **TINY) and resume
    first = train(cfg, resume=resume, verbose=False)
    assert [s["step"] for s in first] == [100, 200]
    with pytest.raises(ValueError, match="--resume"):
        train(SACConfig(steps=300, out=out, **TINY), verbose=False)
    with pytest.raises(ValueError, match="config differs"):
        train(SACConfig(steps=300, out=out, **{**TINY, "hidden": 32}), resume=True, verbose=False)

    ckpt = ocp.CheckpointManager(f"{out}/checkpoints")
    saved = ckpt.restore(200)
    snaps = train(SACConfig(steps=300, out=out, **TINY), resume=True, verbose=False)
    assert [s["step"] for s in snaps] == [100, 200, 300]
    rows = [json.loads(ln) for ln in open(f"{out}/metrics.jsonl")]
    assert [r["step"] for r in rows] == [100, 200, 300]
    assert rows[2]["wall_seconds"] > rows[1]["wall_seconds"]  # wall time carries over the resumption
    final = ocp.CheckpointManager(f"{out}/checkpoints").restore(300)
    assert int(final["env_steps"]) == 300 and int(final["buffer_len"]) == 300
    # the first 200 stored transitions are the checkpointed ones: the buffer was restored, not refilled
    np.testing.assert_array_equal(final["buffer"]["obs"][:200], saved["buffer"]["obs"][:200])
    assert np.any(final["buffer"]["obs"][200:300] != 0)
    # and training went on from the checkpointed networks, with updates in the last chunk
    p200 = load_snapshot(f"{out}/snapshots/step_00000200.npz")[0]
    p300 = load_snapshot(f"{out}/snapshots/step_00000300.npz")[0]
    jax.tree.map(np.testing.assert_array_equal, p200, jax.device_get(saved["actor_params"]))
    assert any(not np.array_equal(a, b) for a, b in zip(jax.tree.leaves(p200), jax.tree.leaves(p300)))
    assert len(traced) <= 2  # fewer where an earlier test of this process traced them
