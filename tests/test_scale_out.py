"""Seeds as one program and several processes (issue: scale out).

``--seeds 3`` must train exactly the three models that three single-seed runs train, and two real processes
on localhost (JAX's distributed runtime, gloo CPU collectives) must train the one-process model."""

import dataclasses
import json
import os
import socket
import subprocess
import sys

import jax
import numpy as np
import orbax.checkpoint as ocp
import pytest

from minsubdt_jax.config import PRESETS, validate
from minsubdt_jax.train import train


# Adam normalises each update, so a parameter whose gradient is ~0 up to float noise (a bias in front of a
# LayerNorm) moves by up to lr per step either way when a batched matmul sums in another order: parameters
# agree to lr * steps, losses and rollouts tightly (the same bound as tests/test_parallel.py).
ADAM_NOISE = 16 * PRESETS["smoke"].learning_rate


def _cfg(path, out, **kw):
    base = dataclasses.replace(PRESETS["smoke"], env="hopper", dataset=path, episode_length=60, out=str(out))
    return validate(dataclasses.replace(base, **kw))


def _params(run_dir, like=None):
    """(last step, parameter leaves) of a run's checkpoint; ``like`` (another run's dir) gives the target tree
    for a checkpoint written by several processes."""
    mngr = ocp.CheckpointManager(os.path.abspath(os.path.join(run_dir, "checkpoints")))
    step = mngr.latest_step()
    if like is None:
        tree = mngr.restore(step)
    else:
        other = ocp.CheckpointManager(os.path.abspath(os.path.join(like, "checkpoints")))
        tree = mngr.restore(step, args=ocp.args.StandardRestore(other.restore(other.latest_step())))
    return step, [np.asarray(x) for x in jax.tree.leaves(tree["params"])]


def _losses(run_dir):
    rows = [json.loads(ln) for ln in open(os.path.join(run_dir, "metrics.jsonl"))]
    return np.array([r["loss_per_model"] for r in rows if "loss" in r])  # (evaluation records share the log)


@pytest.fixture(scope="module")
def single_runs(small_dataset_path, tmp_path_factory):
    """Three ordinary runs, seeds 0, 1, 2."""
    root = tmp_path_factory.mktemp("single")
    return {s: (root / f"s{s}", train(_cfg(small_dataset_path, root / f"s{s}", seed=s), verbose=False))
            for s in range(3)}


def test_seeds_in_one_program_equal_single_seed_runs(single_runs, small_dataset_path, tmp_path):
    out = tmp_path / "seeds3"
    res = train(_cfg(small_dataset_path, out, seed=0, seeds=3), verbose=False)
    assert res["seeds"] == [0, 1, 2]
    step, params = _params(out)
    losses = _losses(out)  # [chunks, 3]
    assert step == 20 and losses.shape == (2, 3)
    for s, (run_dir, single) in single_runs.items():
        step_s, params_s = _params(run_dir)
        assert step_s == 20 and len(params_s) == len(params) > 5
        for a, b in zip(params, params_s):  # the seed axis leads; seed s is row s
            assert a.shape == (3,) + b.shape[1:] and b.shape[0] == 1
            np.testing.assert_allclose(a[s], b[0], rtol=1e-2, atol=ADAM_NOISE)
        np.testing.assert_allclose(losses[:, s], _losses(run_dir)[:, 0], rtol=1e-5)
        ev, ev_s = res["eval_per_model"][s], single["eval"]
        assert ev["seed"] == s and ev_s["seed"] == s
        np.testing.assert_array_equal([len(c) for c in ev["costs"]], [len(c) for c in ev_s["costs"]])
        np.testing.assert_allclose(ev["returns"], ev_s["returns"], rtol=1e-3, atol=1e-3)
    # the seed-level summary: mean ± std over the three seeds' means
    means = [single["eval"]["normalized_score_mean"] for _, single in single_runs.values()]
    np.testing.assert_allclose(res["eval"]["normalized_score_mean"], np.mean(means), rtol=1e-3, atol=1e-4)
    np.testing.assert_allclose(res["eval"]["normalized_score_std"], np.std(means), rtol=1e-2, atol=1e-3)
    assert res["eval"]["episodes"] == 9 and len(res["eval"]["returns"]) == 9


def test_methods_in_one_program_equal_single_method_runs(single_runs, small_dataset_path, tmp_path):
    """--method minsubdt,bc,dt: three models (one per method, seed 0) in one program, only their return tokens
    (and evaluation conditioning) apart; each equals that method's own run. 3 models, as in the 3-seed test: one
    compiled rollout serves both."""
    res = train(_cfg(small_dataset_path, tmp_path / "three", method="minsubdt,bc,dt"), verbose=False)
    assert res["models"] == [{"method": m, "seed": 0} for m in ("minsubdt", "bc", "dt")]
    assert set(res["eval_by_method"]) == {"minsubdt", "bc", "dt"} and "eval" not in res
    _, params = _params(tmp_path / "three")
    losses = _losses(tmp_path / "three")
    singles = {"minsubdt": single_runs[0]}
    for m in ("bc", "dt"):
        singles[m] = (tmp_path / m, train(_cfg(small_dataset_path, tmp_path / m, method=m), verbose=False))
    for i, m in enumerate(("minsubdt", "bc", "dt")):
        run_dir, single = singles[m]
        _, params_1 = _params(run_dir)
        for a, b in zip(params, params_1):
            np.testing.assert_allclose(a[i], b[0], rtol=1e-2, atol=ADAM_NOISE)
        np.testing.assert_allclose(losses[:, i], _losses(run_dir)[:, 0], rtol=1e-5)
        ev = res["eval_per_model"][i]
        assert ev["method"] == m and ev["target_return"] == single["eval"]["target_return"]
        np.testing.assert_allclose(ev["returns"], single["eval"]["returns"], rtol=1e-3, atol=1e-3)
        assert res["eval_by_method"][m]["normalized_score_mean"] == ev["normalized_score_mean"]
    # DT's return tokens are the true returns, not MinSubDT's surrogate: the runs really differ
    assert not np.allclose(losses[:, 0], losses[:, 2])


def test_seeds_with_learned_costs_train_one_cost_model_per_seed(small_dataset_path, tmp_path):
    """--method minsubdt-learned: each seed learns its own costs (eq. 3), so each trains on its own returns-to-go."""
    kw = dict(method="minsubdt-learned", cost_steps=20, eval_episodes=0, steps=10)
    res = train(_cfg(small_dataset_path, tmp_path / "both", seeds=2, **kw), verbose=False)
    accs = [d["learned_costs"]["heldout_pair_accuracy"] for d in res["dataset_per_model"]]
    assert len(accs) == 2
    both = _losses(tmp_path / "both")
    for s in range(2):
        one = train(_cfg(small_dataset_path, tmp_path / f"one{s}", seed=s, **kw), verbose=False)
        assert one["dataset"]["learned_costs"]["heldout_pair_accuracy"] == pytest.approx(accs[s])
        np.testing.assert_allclose(both[:, s], _losses(tmp_path / f"one{s}")[:, 0], rtol=1e-5)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def test_two_processes_train_the_one_process_model(single_runs, small_dataset_path, tmp_path, cli_env):
    """Two real processes on localhost, one CPU device each: the batch is split over them (gloo all-reduce)."""
    out = tmp_path / "two"
    args = [sys.executable, "-m", "minsubdt_jax.train", "--preset", "smoke", "--env", "hopper", "--episode-length",
            "60", "--dataset", small_dataset_path, "--out", str(out), "--num-processes", "2",
            "--coordinator-address", f"localhost:{_free_port()}"]
    from conftest import TEST_XLA_FLAGS

    env = dict(cli_env, JAX_PLATFORMS="cpu", XLA_FLAGS=TEST_XLA_FLAGS)
    procs = [subprocess.Popen(args + ["--process-id", str(i)], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for i in (1, 0)]
    try:
        outs = [p.communicate(timeout=600) for p in procs]
    finally:
        for p in procs:
            p.kill()
    for p, (o, e) in zip(procs, outs):
        assert p.returncode == 0, o[-2000:] + e[-4000:]
    stdout0 = outs[1][0]
    assert "2 device(s) in 2 process(es): 4 sequences each" in stdout0 and "wrote" in stdout0
    assert "dataset" not in outs[0][0] and "wrote" not in outs[0][0]  # process 0 alone reports and writes
    run_dir, single = single_runs[0]
    step, params = _params(out, like=run_dir)
    _, params_1 = _params(run_dir)
    assert step == 20
    for a, b in zip(params, params_1):
        np.testing.assert_allclose(a, b, rtol=1e-2, atol=ADAM_NOISE)
    np.testing.assert_allclose(_losses(out), _losses(run_dir), rtol=2e-4)
    res = json.loads((out / "results.json").read_text())
    # 3 episodes over two processes: 4 rolled out (2 each), gathered, the first 3 scored
    assert res["eval"]["episodes"] == 3
    np.testing.assert_allclose(res["eval"]["returns"], single["eval"]["returns"], rtol=1e-3, atol=1e-3)


def test_datasets_in_one_program_equal_single_dataset_runs(single_runs, small_dataset_path, tmp_path):
    """--dataset a,b: one model per dataset in one program (issue 23's whole env in one program). Each draws only
    its own dataset's episodes, so it trains on the batches of its single-dataset run and equals it; each is
    scored against its own demonstrations."""
    from minsubdt_jax.data import generate_random, save_d4rl

    other = str(tmp_path / "hopper-other.hdf5")  # another dataset: more episodes, shorter, other actions
    save_d4rl(generate_random("hopper", episodes=45, horizon=40, seed=7), other, env="hopper", dynamics="brax",
              physics="mujoco")
    res = train(_cfg(f"{small_dataset_path},{other}", tmp_path / "both"), verbose=False)
    assert res["models"] == [{"dataset": d, "method": "minsubdt", "seed": 0} for d in (small_dataset_path, other)]
    _, params = _params(tmp_path / "both")
    losses = _losses(tmp_path / "both")
    single_other = train(_cfg(other, tmp_path / "other"), verbose=False)
    for i, (run_dir, single) in enumerate([single_runs[0], (tmp_path / "other", single_other)]):
        _, params_1 = _params(run_dir)
        for a, b in zip(params, params_1):
            np.testing.assert_allclose(a[i], b[0], rtol=1e-2, atol=ADAM_NOISE)
        # the first chunk's loss to float32 rounding; the second is the loss of parameters already apart by the Adam
        # noise above, in a program whose episodes are padded to the longer dataset's horizon (other sums): 1.7e-5
        # relative on an AVX-512 CPU (2026-12-02), so 1e-4 here
        np.testing.assert_allclose(losses[0, i], _losses(run_dir)[0, 0], rtol=1e-5)
        np.testing.assert_allclose(losses[:, i], _losses(run_dir)[:, 0], rtol=1e-4)
        assert res["dataset_per_model"][i]["sha256"] == single["dataset"]["sha256"]
        ev = res["eval_per_model"][i]  # scored against its own demos: the same min-subdominance as alone
        np.testing.assert_allclose(ev["returns"], single["eval"]["returns"], rtol=1e-3, atol=1e-3)
        np.testing.assert_allclose(ev["min_subdominance_mean"], single["eval"]["min_subdominance_mean"], rtol=1e-4)
    assert set(res["eval_by_method"]) == {f"{d}/minsubdt" for d in (small_dataset_path, other)}
    from minsubdt_jax.plot import curves  # the curves keep the datasets apart

    assert list(curves(str(tmp_path / "both"))["score"]) == [f"{d}/minsubdt" for d in (small_dataset_path, other)]
    assert not np.allclose(losses[:, 0], losses[:, 1])  # the two datasets really differ
    # cut after the first chunk and resumed: the same models
    train(_cfg(f"{small_dataset_path},{other}", tmp_path / "cut", steps=10, eval_episodes=0), verbose=False)
    train(_cfg(f"{small_dataset_path},{other}", tmp_path / "cut", eval_episodes=0), resume=True, verbose=False)
    step, resumed = _params(tmp_path / "cut")
    assert step == 20
    for a, b in zip(params, resumed):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="each once"):
        _cfg(f"{other},{other}", tmp_path / "twice")
