"""The training CLI as a user runs it: one real ``python -m minsubdt_jax.train`` subprocess, the rest through
``main(argv)`` in this process (the same code path without an interpreter start-up per case)."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from cli_helpers import SMOKE, checkpoint_params, leaves, train_main

# the full run's chosen metrics, parameter average and TensorBoard logger
CHOSEN = ["--costs", "x_velocity,energy,fall", "--ema-decay", "0.9", "--logger", "tensorboard"]


def _run(args, env, check=True):
    p = subprocess.run([sys.executable, "-m", "minsubdt_jax.train", *args], env=env, capture_output=True, text=True,
                       timeout=600)
    if check and p.returncode != 0:
        raise AssertionError(f"exit {p.returncode}\nstdout:\n{p.stdout[-3000:]}\nstderr:\n{p.stderr[-3000:]}")
    return p


@pytest.fixture(scope="module")
def full_run(tmp_path_factory, small_dataset_path, cli_env):
    out = tmp_path_factory.mktemp("runs") / "full"
    p = _run([*SMOKE, *CHOSEN, "--dataset", small_dataset_path, "--out", str(out), "--eval-every", "10"], cli_env)
    return out, p


def test_smoke_train_and_evaluate(full_run):
    """The quick start's shape at the smoke preset, with periodic evaluation: `--eval-every 10` over 20 steps
    logs the evaluation at step 10 and the final one at 20 (normalised score per seed) and plots the score. With
    `--costs x_velocity,energy,fall` the costs are those three, in that order, for the demos and the rollouts;
    with `--ema-decay` the step-10 evaluation also scores the raw parameters."""
    out, p = full_run
    assert "Spearman(-min-subdominance, true return)" in p.stdout
    assert "compiling the train step" in p.stdout  # said before the first chunk's wait
    for name in ("config.json", "dataset.json", "metrics.jsonl", "results.json", "learning_curve.png"):
        assert (out / name).exists(), name
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["preset"] == "smoke" and cfg["steps"] == 20 and cfg["episode_length"] == 60 and cfg["eval_every"] == 10
    metrics = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    losses = [m for m in metrics if "loss" in m]
    evals = [m for m in metrics if "eval_normalized_score" in m]
    assert [m["step"] for m in losses] == [10, 20] and all(np.isfinite(m["loss"]) for m in losses)
    assert [(m["step"], m["final"]) for m in evals] == [(10, False), (20, True)]
    assert all(len(m["eval_normalized_score"]) == 1 and np.isfinite(m["eval_normalized_score"][0]) for m in evals)
    res = json.loads((out / "results.json").read_text())
    ev = res["eval"]
    assert ev["episodes"] == 3 and 1 <= ev["length_mean"] <= 60
    assert evals[-1]["eval_normalized_score"] == [ev["normalized_score_mean"]]
    assert list(ev["costs_mean"]) == list(res["dataset"]["costs_mean"]) == ["x_velocity", "energy", "fall"]
    assert [m["name"] for m in res["dataset"]["cost_metrics"]] == ["x_velocity", "energy", "fall"]
    assert "energy" in p.stdout.split("costs (lower is better")[1] and len(ev["costs"][0]) == 3
    assert "eval_raw_normalized_score" in evals[0] and "eval_raw_normalized_score" not in evals[1]
    tb = _tensorboard_scalars(out / "tensorboard")  # the same records, read back from the event files
    assert tb["eval_normalized_score/minsubdt-s0"] == [(10, pytest.approx(evals[0]["eval_normalized_score"][0])),
                                                       (20, pytest.approx(ev["normalized_score_mean"]))]
    assert [s for s, _ in tb["loss"]] == [10, 20]
    assert 0 <= ev["min_subdominance_mean"] <= 3 and np.isfinite(ev["normalized_score_mean"])  # K beta, K = 3
    assert res["dataset"]["episodes"] == 32 and res["references"]["dynamics"] == "brax"
    assert res["method"] == {"name": "minsubdt", "label": "MinSubDT (engg. costs)", "agent": "dt"}
    assert res["platform"]["backend"] == "cpu" and len(res["dataset"]["sha256"]) == 64
    import matplotlib.image

    assert matplotlib.image.imread(out / "learning_curve.png").shape[1] == 1300  # loss, score, min-subdominance


def test_resume_reaches_the_same_parameters(full_run, tmp_path, small_dataset_path, capsys):
    """Stop after the first chunk (10 steps), resume to 20: identical to the uninterrupted run (which also
    evaluated at step 10: evaluation does not touch training)."""
    out = tmp_path / "resumed"
    common = [*SMOKE, *CHOSEN, "--dataset", small_dataset_path, "--out", str(out), "--eval-episodes", "0"]
    assert train_main([*common, "--steps", "10"], capsys)[0] == 0
    assert checkpoint_params(out)[0] == 10
    code, _ = train_main([*common, "--steps", "20", "--resume"], capsys)
    assert code == 0
    step_a, a = checkpoint_params(full_run[0])
    step_b, b = checkpoint_params(out)
    assert step_a == step_b == 20
    leaves_a, leaves_b = [np.asarray(x) for x in leaves(a)], [np.asarray(x) for x in leaves(b)]
    assert len(leaves_a) == len(leaves_b) > 5
    for x, y in zip(leaves_a, leaves_b):
        np.testing.assert_array_equal(x, y)
    metrics = [json.loads(line)["step"] for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert metrics == [10, 20]


def _tensorboard_scalars(folder) -> dict:
    """``{tag: [(step, value)]}`` from tensorboardX event files, read as TFRecords (length, crc, data, crc)."""
    import struct

    from tensorboardX.proto.event_pb2 import Event

    out = {}
    for path in sorted(folder.iterdir()):
        buf = path.read_bytes()
        i = 0
        while i < len(buf):
            (n,) = struct.unpack("<Q", buf[i:i + 8])
            ev = Event.FromString(buf[i + 12:i + 12 + n])
            i += 12 + n + 4
            for v in ev.summary.value:
                out.setdefault(v.tag, []).append((ev.step, v.simple_value))
    return out


def test_existing_run_needs_resume(full_run, small_dataset_path, capsys):
    out, _ = full_run
    code, err = train_main([*SMOKE, "--dataset", small_dataset_path, "--out", str(out)], capsys)
    assert code == 2 and "pass --resume" in err
    code, err = train_main([*SMOKE, "--dataset", small_dataset_path, "--out", str(out), "--resume", "--batch-size", "4"],
                      capsys)
    assert code == 2 and "config differs" in err and "batch_size" in err


def test_named_dataset_is_recorded_on_first_use_then_reused(tmp_path, capsys, monkeypatch):
    """``--dataset medium`` records hopper medium from the committed policy into the cache, once. (The horizon is
    the default 1000, so the recording program is test_generate's.)"""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    args = [*SMOKE, "--episode-length", "1000", "--dataset", "medium", "--steps", "10", "--eval-episodes", "0"]
    code, out = train_main([*args, "--out", str(tmp_path / "a")], capsys, "out")
    assert code == 0 and "hopper/medium:" in out and "transitions" in out  # the recording summary
    res = json.loads((tmp_path / "a" / "results.json").read_text())["dataset"]
    assert res["path"].startswith(str(tmp_path / "xdg")) and "hopper-medium-t2000-h1000-s0" in res["path"]
    assert res["transitions"] >= 2000 and os.path.exists(res["path"])
    code, out = train_main([*args, "--out", str(tmp_path / "b")], capsys, "out")
    assert code == 0 and "hopper/medium:" not in out  # loaded from the cache, not recorded again
    assert json.loads((tmp_path / "b" / "results.json").read_text())["dataset"] == res
    assert json.loads((tmp_path / "b" / "dataset.json").read_text())["sha256"] == res["sha256"]


def test_data_that_cannot_be_trained_on_stops_before_anything_is_written(tmp_path, small_dataset_path, capsys):
    """Wrong env for the data, one episode, values that overflow float32: one error line, exit 2, no run dir."""
    import h5py

    out = tmp_path / "never"
    code, err = train_main([*SMOKE, "--env", "walker", "--dataset", small_dataset_path, "--out", str(out)], capsys)
    assert code == 2 and err.count("error:") == 1 and "recorded in hopper, not in walker" in err and not out.exists()
    with h5py.File(small_dataset_path) as f:
        flat = {k: f[k][()] for k in ("observations", "actions", "rewards", "terminals", "timeouts")}
    first = int(np.argmax(flat["terminals"] | flat["timeouts"])) + 1
    cases = {
        "one.hdf5": ({k: v[:first] for k, v in flat.items()}, "has 1 episode; min-subdominance"),
        # finite in float64, inf in float32: the file passes a NaN/inf check done before the conversion
        "big.hdf5": ({**flat, "observations": np.where(np.arange(len(flat["rewards"]))[:, None] == 7, 1e39,
                                                       flat["observations"].astype(np.float64))}, "beyond ±3.4e38"),
    }
    for name, (arrays, message) in cases.items():
        with h5py.File(tmp_path / name, "w") as f:
            for k, v in arrays.items():
                f.create_dataset(k, data=v)
        code, err = train_main([*SMOKE, "--dataset", str(tmp_path / name), "--out", str(out)], capsys)
        assert code == 2 and err.count("error:") == 1 and message in err and "Traceback" not in err, err
        assert not out.exists()


def test_diverging_training_stops_with_an_error_and_no_results(tmp_path, small_dataset_path, capsys):
    out = tmp_path / "nan"
    code, err = train_main([*SMOKE, "--dataset", small_dataset_path, "--out", str(out), "--learning-rate", "1e30"], capsys)
    assert code == 2 and "training diverged: non-finite loss" in err and "Traceback" not in err
    assert not (out / "results.json").exists() and not (out / "metrics.jsonl").exists()
    assert not any(d.isdigit() for d in os.listdir(out / "checkpoints"))


def test_resume_refuses_fewer_steps_and_other_data_and_survives_a_torn_log(tmp_path, small_dataset_path, capsys):
    import shutil

    data = tmp_path / "data.hdf5"
    shutil.copy(small_dataset_path, data)
    out = tmp_path / "run"
    common = [*SMOKE, "--dataset", str(data), "--out", str(out), "--eval-episodes", "0"]
    assert train_main(common, capsys)[0] == 0  # 20 steps
    before = {n: (out / n).read_bytes() for n in ("config.json", "dataset.json", "metrics.jsonl")}
    code, err = train_main([*common, "--steps", "10", "--resume"], capsys)
    assert code == 2 and "--steps 10 is below the run's last checkpoint, step 20" in err
    # the same path, other contents (one action changed)
    from minsubdt_jax.data import load_d4rl, save_d4rl
    from minsubdt_jax.data.dataset import Trajectories

    d = load_d4rl(data)
    actions = d.actions.copy()
    actions[0, 0, 0] += 0.5
    save_d4rl(Trajectories(d.observations, actions, d.rewards, d.lengths, d.terminals), data)
    code, err = train_main([*common, "--steps", "30", "--resume"], capsys)
    assert code == 2 and "the dataset differs from the one the run started on" in err
    assert {n: (out / n).read_bytes() for n in before} == before  # refusals change nothing
    shutil.copy(small_dataset_path, data)
    # a kill while a metrics line was being written leaves half a line: resume drops it, keeps the rest
    with open(out / "metrics.jsonl", "a") as f:
        f.write('{"step": 30, "loss": 0.')
    assert train_main([*common, "--steps", "30", "--resume"], capsys)[0] == 0
    steps = [json.loads(ln)["step"] for ln in (out / "metrics.jsonl").read_text().splitlines()]
    assert steps == [10, 20, 30]
    assert json.loads((out / "config.json").read_text())["steps"] == 30


def test_learned_costs_and_behaviour_cloning(tmp_path, small_dataset_path):
    """--method minsubdt-learned trains eq. 3 costs and reports them; --method bc sets every return token 0."""
    import dataclasses

    from minsubdt_jax.config import PRESETS, validate
    from minsubdt_jax.methods import get_method
    from minsubdt_jax.pipeline import prepare
    from minsubdt_jax.train import train

    base = dataclasses.replace(PRESETS["smoke"], env="hopper", dataset=small_dataset_path, episode_length=60)
    bc = prepare(validate(dataclasses.replace(base, method="bc")), get_method("bc"), verbose=False)
    assert np.all(np.asarray(bc.sampler.returns_to_go) == 0) and bc.target_return == 0.0
    res = train(validate(dataclasses.replace(base, method="minsubdt-learned", cost_dim=3, cost_steps=30,
                                             out=str(tmp_path / "learned"))), verbose=False)
    rep = res["dataset"]["learned_costs"]
    assert res["dataset"]["min_subdominance_features"] == "learned" and len(rep["alpha"]) == 3
    assert 0 <= rep["heldout_pair_accuracy"] <= 1 and np.isfinite(rep["final_loss"])
    agree = rep["spearman_with_metrics"]  # each learned feature's rank agreement with each chosen metric
    assert list(agree) == ["learned_0", "learned_1", "learned_2"] and all(
        list(v) == ["x_velocity", "fall"] and all(-1 <= x <= 1 for x in v.values() if np.isfinite(x))
        for v in agree.values())
    ev = res["eval"]
    assert np.isfinite(ev["learned_min_subdominance_mean"]) and 0 <= ev["better_than_mean_demo_share"] <= 1
    assert len(ev["costs"]) == 3 and len(res["dataset"]["costs_sample"]) == 32


def test_config_file_round_trips_flags_override_it_and_bad_files_are_refused(tmp_path, capsys, monkeypatch):
    """A run's config.json read back with --config is the same Config; a flag overrides it; a partial YAML
    starts from its preset; a file that does not parse, names an unknown field or has a wrong type is one error
    and nothing is written. Every field has a help text (from its comment in config.py)."""
    import dataclasses

    from minsubdt_jax.config import PRESETS, Config
    from minsubdt_jax.train import parse_args
    from minsubdt_jax.flags import field_help

    cfg = dataclasses.replace(PRESETS["cpu"], env="hopper", seeds=2, costs="x_velocity,energy", ema_decay=0.99,
                              learning_rate=5e-4, out=str(tmp_path / "r"), target_return=-0.5)
    path = tmp_path / "config.json"
    path.write_text(cfg.to_json())
    assert parse_args(["--config", str(path)]) == (cfg, False)
    assert parse_args(["--config", str(path), "--steps", "7", "--resume"]) == (dataclasses.replace(cfg, steps=7), True)
    (tmp_path / "c.yaml").write_text("preset: smoke\nsteps: 5\nlearning_rate: 1\n")
    assert parse_args(["--config", str(tmp_path / "c.yaml")])[0] == dataclasses.replace(PRESETS["smoke"], steps=5,
                                                                                         learning_rate=1.0)
    from minsubdt_jax.agents import AGENTS  # a critic agent with its own study setting gets it; --steps overrides it

    monkeypatch.setitem(AGENTS["iql"].presets, "study", dict(steps=1234, lr_schedule="constant", ema_decay=0.999))
    study_iql = parse_args(["--preset", "study", "--method", "iql"])[0]
    assert (study_iql.steps, study_iql.lr_schedule, study_iql.ema_decay) == (1234, "constant", 0.999)
    assert parse_args(["--preset", "study", "--method", "iql", "--steps", "9"])[0].steps == 9
    assert parse_args(["--preset", "study"])[0] == PRESETS["study"]
    quick = parse_args([])[0]  # the README's first command: study's recipe over 3k steps (issue 75: 4.0 at cpu's)
    assert quick == PRESETS["quick"] and (quick.steps, quick.learning_rate, quick.lr_schedule, quick.ema_decay) == (
        3000, 1e-3, "cosine", 0.999) and (quick.embed_dim, quick.n_layers) == (PRESETS["study"].embed_dim, 2)
    out = tmp_path / "never"
    for text, name, msg in (("steps: [\n", "a.yaml", "does not parse"), ('{"stpes": 3}', "b.json", "unknown field"),
                            ('{"steps": "3"}', "c.json", "field 'steps' must be int")):
        (tmp_path / name).write_text(text)
        code, err = train_main(["--config", str(tmp_path / name), "--out", str(out)], capsys)
        assert code == 2 and msg in err and err.count("\n") == 1 and not out.exists(), err
    helps = field_help(Config)
    assert all(helps.get(f.name) for f in dataclasses.fields(Config)), [f.name for f in dataclasses.fields(Config)
                                                                        if not helps.get(f.name)]


def test_plot_compares_runs_with_mean_and_std_over_seeds(full_run, tmp_path):
    """`python -m minsubdt_jax.plot` on the full run and a hand-written two-method, two-seed log: one PNG; the
    curves it draws are the seeds' mean and std (hand values); a folder without a log is one error, no PNG."""
    import matplotlib.image

    from minsubdt_jax.plot import curves, main as plot_main

    other = tmp_path / "two"
    other.mkdir()
    recs = [{"step": 5, "loss": 1.5, "loss_per_model": [1.0, 2.0, 1.0, 2.0]},
            {"step": 5, "eval_normalized_score": [10.0, 20.0, 30.0, 50.0], "eval_min_subdominance": [1, 1, 0, 0],
             "eval_method": ["dt", "dt", "bc", "bc"], "eval_seed": [0, 1, 0, 1], "final": True}]
    (other / "metrics.jsonl").write_text("\n".join(map(json.dumps, recs)) + "\n")
    c = curves(str(other))
    assert c["loss"][1].tolist() == [1.5] and c["loss"][2].tolist() == [0.5]
    assert c["score"]["dt"][1].tolist() == [15.0] and c["score"]["bc"][2].tolist() == [10.0]
    png = tmp_path / "runs.png"
    assert plot_main([str(full_run[0]), str(other), "--out", str(png)]) == 0
    assert matplotlib.image.imread(png).shape[1] == 1500
    assert plot_main([str(tmp_path / "none"), "--out", str(tmp_path / "x.png")]) == 2
    assert not (tmp_path / "x.png").exists()
