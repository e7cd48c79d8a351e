"""Data parallelism over a device mesh: the sharded train step and the sharded evaluation equal the
single-device ones (issue: scale out).

The 2-device side runs in a subprocess with two forced CPU devices (XLA_FLAGS must be set before jax starts)
and saves its results; the 1-device references are computed here, in the test process, where the evaluation
is the smoke preset's (3 episodes of hopper, 60 steps), compiled once for the whole session."""

import os
import subprocess
import sys
import textwrap

import numpy as np

COMMON = textwrap.dedent("""
    import dataclasses, jax, numpy as np
    from minsubdt_jax.agents.base import PolicyInputs, init_state, make_optimizer, make_train_chunk
    from minsubdt_jax.agents.dt.agent import make_dt_agent
    from minsubdt_jax.config import PRESETS
    from minsubdt_jax.data import Trajectories, sampler_data
    from minsubdt_jax.scoring import Scoring, evaluate_policy
    from minsubdt_jax.parallel import make_mesh, replicate

    def run(devices):
        rng = np.random.default_rng(0)
        n, T, obs, act = 12, 40, 5, 3
        ds = Trajectories(rng.normal(size=(n, T, obs)).astype(np.float32),
                          rng.uniform(-1, 1, (n, T, act)).astype(np.float32), rng.normal(size=(n, T)).astype(np.float32),
                          rng.integers(5, T + 1, n).astype(np.int32), np.zeros(n, bool))
        mean, std = ds.state_stats()
        data = sampler_data(ds, ds.rewards, mean, std)
        cfg = dataclasses.replace(PRESETS["smoke"], dropout=0.1)
        agent, tx = make_dt_agent(cfg, obs, act, 100), make_optimizer(cfg)
        mesh = make_mesh(devices, cfg.batch_size)
        state, dd = replicate((init_state(agent, tx, jax.random.PRNGKey(0)), data), mesh)
        chunk = make_train_chunk(agent, tx, cfg.batch_size, 8, mesh)
        state, losses = chunk(state, dd)
        state, more = chunk(state, dd)
        out = {"losses": np.concatenate([losses, more]), "all_reduce": devices > 1 and "all-reduce" in
               chunk.lower(state, dd).compile().as_text()}
        out.update({f"param{i}": np.asarray(x) for i, x in enumerate(jax.tree.leaves(state.params))})
        # evaluation of the smoke preset's hopper DT: 3 episodes; over 2 devices 4 run, the first 3 are scored
        hop = make_dt_agent(cfg, 11, 3, 60)
        pol = PolicyInputs(params=init_state(hop, tx, jax.random.PRNGKey(0)).params,
                           state_mean=np.zeros(11, np.float32), state_std=np.ones(11, np.float32),
                           target_return=np.float32(0), rtg_scale=np.float32(1), subtract_rewards=np.float32(0))
        stacked = jax.tree.map(lambda x: np.asarray(x)[None], pol)  # one model: a seed axis of 1
        demo = np.random.default_rng(1).uniform(0, 1, (6, 2))
        ev = evaluate_policy("hopper", hop, replicate(stacked, mesh), num_episodes=3, horizon=60, seeds=[4],
                             scoring=Scoring(demo_costs=demo), mesh=mesh)[0]  # on 1 device: the program train() evaluates with
        out.update(returns=ev.returns, lengths=ev.lengths, costs=ev.costs)
        return out
""")

SUBPROCESS = COMMON + textwrap.dedent("""
    import sys
    assert jax.local_device_count() == 2, jax.devices()
    out = run(2)
    for bad, message in ((3, "2 local device"), (7, "divisible")):
        try:
            make_mesh(bad) if bad == 3 else make_mesh(2, batch_size=bad)
        except ValueError as e:
            assert message in str(e), e
        else:
            raise AssertionError(f"make_mesh must refuse {bad}")
    # the rollout itself ran split: its output lives on both devices
    from minsubdt_jax.envs import make_seed_rollout
    cfg = PRESETS["smoke"]
    hop = make_dt_agent(cfg, 11, 3, 60)
    pol = PolicyInputs(params=init_state(hop, make_optimizer(cfg), jax.random.PRNGKey(0)).params,
                       state_mean=np.zeros(11, np.float32), state_std=np.ones(11, np.float32),
                       target_return=np.float32(0), rtg_scale=np.float32(1), subtract_rewards=np.float32(0))
    mesh = make_mesh(2, cfg.batch_size)  # inputs placed as evaluate_policy places them: its compiled program
    ro = make_seed_rollout("hopper", hop.policy, 4, 60, mesh, physics="auto", dynamics="brax", threads=0)(
        replicate(jax.tree.map(lambda x: np.asarray(x)[None], pol), mesh), hop.initial_carry(4),
        jax.random.PRNGKey(4)[None])
    # C MuJoCo runs on one process's cores: on this 2-device mesh it is refused, one error line, nothing written
    import contextlib, io, os, tempfile
    from minsubdt_jax.train import main
    never, err = os.path.join(tempfile.mkdtemp(), "never"), io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main(["--preset", "smoke", "--env", "hopper", "--physics", "mujoco", "--devices", "2", "--out", never])
    assert code == 2 and err.getvalue().count("error:") == 1 and "--physics mujoco runs on one" in err.getvalue()
    assert not os.path.exists(never), never
    out["rollout_devices"] = len(ro.observations.sharding.device_set)
    out["rollout_replicated"] = ro.observations.sharding.is_fully_replicated
    np.savez(sys.argv[1], **out)
""")


def test_sharded_step_and_evaluation_equal_single_device(tmp_path):
    namespace = {}
    exec(COMMON, namespace)
    one = namespace["run"](1)
    from conftest import TEST_XLA_FLAGS

    env = dict(os.environ, XLA_FLAGS=TEST_XLA_FLAGS + " --xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu")
    p = subprocess.run([sys.executable, "-c", SUBPROCESS, str(tmp_path / "two.npz")], env=env, capture_output=True,
                       text=True, timeout=600)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-4000:]
    two = dict(np.load(tmp_path / "two.npz"))
    assert two["all_reduce"], "no gradient all-reduce in the 2-device program"
    assert int(two["rollout_devices"]) == 2 and not two["rollout_replicated"]
    np.testing.assert_allclose(one["losses"], two["losses"], rtol=2e-4, atol=1e-6)
    # Adam normalises each update, so a parameter whose gradient is ~0 (float noise, summed in another order
    # on 2 devices) may move by up to lr per step either way: parameters agree to lr * steps, losses tightly
    n_params = len([k for k in one if k.startswith("param")])
    assert n_params > 5
    for i in range(n_params):
        np.testing.assert_allclose(one[f"param{i}"], two[f"param{i}"], rtol=1e-2, atol=16 * 1e-3)
    # 3 evaluation episodes over 2 devices (4 run, the first 3 scored) equal 3 episodes on one device
    assert one["returns"].shape == two["returns"].shape == (3,)
    np.testing.assert_array_equal(one["lengths"], two["lengths"])
    np.testing.assert_allclose(one["returns"], two["returns"], rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(one["costs"], two["costs"], rtol=1e-4, atol=1e-5)
