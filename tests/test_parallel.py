"""Data parallelism over a device mesh: the sharded train step and the sharded evaluation equal the
single-device ones (issue: scale out).

Runs in a subprocess with two forced CPU devices (XLA_FLAGS must be set before jax starts)."""

import os
import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent("""
    import dataclasses, jax, numpy as np
    assert jax.local_device_count() == 2, jax.devices()
    from minsubdt_jax.config import PRESETS
    from minsubdt_jax.data import Trajectories, sampler_data
    from minsubdt_jax.parallel import make_mesh, replicate
    from minsubdt_jax.train import init_state, make_model, make_optimizer, make_train_chunk

    rng = np.random.default_rng(0)
    n, T, obs, act = 12, 40, 5, 3
    ds = Trajectories(rng.normal(size=(n, T, obs)).astype(np.float32), rng.uniform(-1, 1, (n, T, act)).astype(np.float32),
                      rng.normal(size=(n, T)).astype(np.float32), rng.integers(5, T + 1, n).astype(np.int32),
                      np.zeros(n, bool))
    mean, std = ds.state_stats()
    data = sampler_data(ds, ds.rewards, mean, std)
    cfg = dataclasses.replace(PRESETS["smoke"], dropout=0.1)
    model, tx = make_model(cfg, act, 100), make_optimizer(cfg)
    out = {}
    for d in (1, 2):
        mesh = make_mesh(d, cfg.batch_size)
        state, dd = replicate((init_state(model, tx, cfg, obs), data), mesh)
        chunk = make_train_chunk(model, tx, cfg, 8, mesh)
        state, losses = chunk(state, dd)
        state, more = chunk(state, dd)
        out[d] = (np.concatenate([losses, more]), jax.tree.leaves(state.params))
        if d == 2:  # the step really ran partitioned: its batch-dependent work is split over both devices
            txt = chunk.lower(state, dd).compile().as_text()
            assert "all-reduce" in txt, "no gradient all-reduce in the 2-device program"
    np.testing.assert_allclose(out[1][0], out[2][0], rtol=2e-4, atol=1e-6)
    # Adam normalises each update, so a parameter whose gradient is ~0 (float noise, summed in another order
    # on 2 devices) may move by up to lr per step either way: parameters agree to lr * steps, losses tightly
    for a, b in zip(out[1][1], out[2][1]):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-2, atol=16 * cfg.learning_rate)
    try:
        make_mesh(3)
    except ValueError as e:
        assert "2 local device" in str(e)
    else:
        raise AssertionError("asking for 3 of 2 devices must fail")
    try:
        make_mesh(2, batch_size=7)
    except ValueError as e:
        assert "divisible" in str(e)
    else:
        raise AssertionError("an odd batch over 2 devices must fail")
    # evaluation: 3 episodes over 2 devices (padded to 4, the first 3 scored) equal 3 episodes on one device
    from minsubdt_jax.evaluate import PolicyParams, evaluate
    hop = make_model(cfg, 3, 100)
    pol = PolicyParams(model=init_state(hop, tx, cfg, 11).params, state_mean=np.zeros(11, np.float32),
                       state_std=np.ones(11, np.float32), target_return=np.float32(0), rtg_scale=np.float32(1),
                       subtract_rewards=np.float32(0))
    demo = rng.uniform(0, 1, (6, 2))
    evs = {d: evaluate("hopper", hop, pol, cfg.context_len, demo, num_episodes=3, horizon=30, seed=4,
                       mesh=None if d == 1 else make_mesh(d)) for d in (1, 2)}
    assert evs[1].returns.shape == evs[2].returns.shape == (3,)
    np.testing.assert_array_equal(evs[1].lengths, evs[2].lengths)
    np.testing.assert_allclose(evs[1].returns, evs[2].returns, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(evs[1].costs, evs[2].costs, rtol=1e-4, atol=1e-5)
    from minsubdt_jax.evaluate import _seed_rollout
    run2 = _seed_rollout("hopper", hop, 4, 30, make_mesh(2))
    stacked = jax.tree.map(lambda x: np.asarray(x)[None], pol)
    from minsubdt_jax.evaluate import empty_context
    ro = run2(stacked, empty_context(4, cfg.context_len, 11, 3), jax.random.PRNGKey(4)[None])
    assert len(ro.observations.sharding.device_set) == 2 and not ro.observations.sharding.is_fully_replicated
    print("OK", out[1][0][-1], out[2][0][-1])
""")


def test_sharded_step_and_evaluation_equal_single_device():
    env = dict(os.environ)
    env["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2"
    env["JAX_PLATFORMS"] = "cpu"
    p = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0 and "OK" in p.stdout, p.stdout[-2000:] + p.stderr[-4000:]
