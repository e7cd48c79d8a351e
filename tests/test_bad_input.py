"""Bad input and odd settings (issue 56): the training CLI's flags and settings out of range, non-finite numbers, a plot
into a missing folder, a malformed Minari id, a configuration that cannot fit in memory, actions outside the bounds,
the help's lists, the peer check without its venv, the experiment scripts' flags. Each is one clear line, no
traceback, and writes nothing."""

import json
import os

import pytest

from cli_helpers import SMOKE, train_main


@pytest.mark.parametrize("flag,value", [("--target-return", "nan"), ("--learning-rate", "inf"),
                                        ("--beta=-inf", None), ("--rtg-scale", "nan")])
def test_a_non_finite_number_is_one_error_before_anything_is_written(tmp_path, capsys, flag, value):
    """`--target-return nan` used to run and write NaN scores and a bare NaN into results.json: every float flag must
    be finite (one error line, exit 2, no run directory)."""
    out = tmp_path / "never"
    code, err = train_main([*SMOKE, flag, *([value] if value else []), "--out", str(out)], capsys)
    assert code == 2 and f"{flag.split('=')[0]} must be a finite number" in err and not out.exists()


def test_plot_into_a_missing_folder_is_one_error(tmp_path, capsys):
    from minsubdt_jax.plot import main as plot_main

    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "metrics.jsonl").write_text(json.dumps({"step": 1, "loss": 1.0, "loss_per_model": [1.0]}) + "\n")
    assert plot_main([str(tmp_path / "run"), "--out", str(tmp_path / "missing" / "x.png")]) == 2
    err = capsys.readouterr().err
    assert "the folder" in err and "does not exist" in err and err.strip().count("\n") == 0
    assert not (tmp_path / "missing").exists()


def test_a_malformed_minari_id_is_one_error_and_leaves_no_folder(small_dataset_path, monkeypatch, tmp_path, capsys):
    """`--export-minari "bad id with spaces"` left a folder under the Minari datasets path that broke every later
    `minari:` load until removed by hand. A malformed id (or one without -v<version>) is one error line before
    anything is recorded or written, and Minari's own listing still works."""
    import minari

    from minsubdt_jax.data.__main__ import main as data_main

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    for bad in ("bad id with spaces", "minsubdt/hopper-medium"):
        assert data_main(["--env", "hopper", "--dataset", small_dataset_path, "--export-minari", bad]) == 2
        err = capsys.readouterr().err
        assert "is not a Minari dataset id" in err and err.strip().count("\n") == 0
    assert not (tmp_path / "minari").exists() or not os.listdir(tmp_path / "minari")
    assert minari.list_local_datasets() == {}


def test_a_configuration_that_cannot_fit_in_memory_is_one_error(tmp_path, small_dataset_path, capsys):
    """A context far beyond the horizon, or a huge batch, was an out-of-memory kill without a message or a 42-line
    XLA traceback. A context longer than an episode is refused, and a train step whose estimated memory exceeds
    what the device has is one error line naming the flags, before anything is written."""
    out = tmp_path / "never"
    code, err = train_main([*SMOKE, "--context-len", "80", "--out", str(out)], capsys)
    assert code == 2 and "--context-len 80 is longer than an episode" in err and not out.exists()
    for flags in (["--context-len", "5000", "--episode-length", "5000"], ["--batch-size", "100000000"]):
        code, err = train_main([*SMOKE, "--dataset", small_dataset_path, *flags, "--out", str(out)], capsys)
        assert code == 2 and "GiB available: lower --context-len or --batch-size" in err, err
        assert err.strip().count("\n") == 0 and not out.exists()


def test_the_memory_estimate_is_above_xlas_own_and_within_2x():
    """The estimate the check uses against XLA's own temporary memory for one compiled DT step (smoke preset, and
    with 4x the context): never below it, at most 2x above."""
    import dataclasses

    import jax
    import numpy as np

    from minsubdt_jax.agents.base import init_state, make_optimizer, make_train_step
    from minsubdt_jax.agents.dt.agent import make_dt_agent, train_step_bytes
    from minsubdt_jax.config import PRESETS
    from minsubdt_jax.data import Trajectories, sampler_data

    n, T, obs, act = 4, 40, 11, 3
    ds = Trajectories(np.zeros((n, T, obs), np.float32), np.zeros((n, T, act), np.float32), np.zeros((n, T), np.float32),
                      np.full(n, T, np.int32), np.zeros(n, bool))
    data = sampler_data(ds, np.zeros((n, T)), np.zeros(obs, np.float32), np.ones(obs, np.float32))
    for over in ({}, {"context_len": 20, "batch_size": 32}):
        cfg = dataclasses.replace(PRESETS["smoke"], **over)
        agent, tx = make_dt_agent(cfg, obs, act, T), make_optimizer(cfg)
        xla = jax.jit(make_train_step(agent, tx, cfg.batch_size)).lower(
            init_state(agent, tx, jax.random.PRNGKey(0)), data).compile().memory_analysis().temp_size_in_bytes
        assert xla <= train_step_bytes(cfg, 1) <= 2 * xla, (over, xla, train_step_bytes(cfg, 1))


def test_actions_outside_the_bounds_are_refused_with_one_line(small_dataset, tmp_path, capsys):
    """A dataset whose actions lie outside [-1, 1] (x3) was trained on silently. The envs clip every action to
    [-1, 1], so such data cannot come from them: one error line, nothing written."""
    import dataclasses

    from minsubdt_jax.data import save_d4rl

    path = str(tmp_path / "x3.hdf5")
    save_d4rl(dataclasses.replace(small_dataset, actions=3 * small_dataset.actions), path)
    out = tmp_path / "never"
    code, err = train_main([*SMOKE, "--dataset", path, "--out", str(out)], capsys)
    assert code == 2 and "outside hopper's action bounds [-1, 1]" in err and err.strip().count("\n") == 0
    assert not out.exists()


def test_the_console_help_lists_every_method_and_metric_and_tags_are_consistent(capsys, tmp_path, monkeypatch):
    """What a newcomer reads: `train --help` names every method and says where evaluation runs (C MuJoCo on a CPU,
    not only MJX); `train --costs list` prints the metrics (it was an error); `data --help` explains --env, --seed
    and --horizon; TensorBoard tags every per-model list `<metric>/<method>-s<seed>` (the loss was tagged
    `loss_per_model/0`); the learning curve's figure is titled with env, dataset and method."""
    from minsubdt_jax import loggers, plot
    from minsubdt_jax.train import parse_args
    from minsubdt_jax.data.__main__ import main as data_main
    from minsubdt_jax.methods import METHODS

    with pytest.raises(SystemExit):
        parse_args(["--help"])
    text = " ".join(capsys.readouterr().out.split()).replace("- ", "-")  # argparse wraps lines after a hyphen
    assert all(m in text for m in METHODS) and "C MuJoCo on a CPU" in text
    with pytest.raises(SystemExit) as e:
        parse_args(["--env", "hopper", "--costs", "list"])
    assert e.value.code == 0 and "x_velocity:" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        data_main(["--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    for flag in ("--env {hopper,walker,halfcheetah} the environment", "--seed SEED the recording's seed",
                 "--horizon HORIZON the episodes' length limit"):
        assert flag in help_text, flag
    tags = loggers.scalars({"step": 10, "loss_per_model": [0.5, 0.7]}, ["minsubdt-s0", "dt-s0"])
    assert set(tags) == {"loss_per_model/minsubdt-s0", "loss_per_model/dt-s0", "loss_per_model/mean"}
    ev = loggers.scalars({"step": 10, "eval_return": [1.0, 2.0], "eval_method": ["minsubdt", "dt"],
                          "eval_seed": [0, 0]}, ["minsubdt-s0", "dt-s0"])
    assert set(ev) == {"eval_return/minsubdt-s0", "eval_return/dt-s0", "eval_return/mean"}
    (tmp_path / "metrics.jsonl").write_text(json.dumps({"step": 10, "loss": 0.5, "loss_per_model": [0.5]}) + "\n")
    titles = []
    import matplotlib.figure
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", lambda fig, *_a, **_k: titles.append(fig._suptitle))
    plot.plot_learning_curve(str(tmp_path / "metrics.jsonl"), str(tmp_path / "c.png"), "hopper medium: dt (1 seed)")
    assert titles[0].get_text() == "hopper medium: dt (1 seed)"


@pytest.mark.parametrize("script", ["peer_dt", "peer_critics"])
def test_the_peer_check_without_its_venv_is_one_line_saying_how(capsys, script):
    """experiments/peer_dt.py and peer_critics.py need torch and d3rlpy, which are not ours: without them, one error
    line with the README's command that makes their venv (it was an ImportError traceback)."""
    import importlib
    import importlib.util

    if importlib.util.find_spec("d3rlpy") is not None:
        pytest.skip("d3rlpy is installed here")
    with pytest.raises(SystemExit) as e:
        importlib.import_module(script).main(["run", "--env", "hopper"])  # experiments/ (pyproject's pythonpath)
    err = capsys.readouterr().err
    assert e.value.code == 2 and "python3 -m venv .venv-peer" in err and "Traceback" not in err, err


@pytest.mark.parametrize("script,argv,says", [
    ("cost_features", ["--envs", "nope"], "invalid choice: 'nope'"),
    ("cost_features", ["--datasets", "nope"], "invalid choice: 'nope'"),
    ("datasets", ["--envs", "nope"], "invalid choice: 'nope'"),
    ("compare_runs", ["/nonexistent-a", "/nonexistent-b"], "not a run directory")])
def test_an_experiment_scripts_bad_input_is_one_error_line(script, argv, says, capsys):
    """A newcomer's pass over experiments/ (2026-12-06): these were tracebacks."""
    import importlib

    with pytest.raises(SystemExit) as e:
        importlib.import_module(script).main(argv)
    err = capsys.readouterr().err
    assert e.value.code == 2 and says in err and "Traceback" not in err, err


def test_bad_input_is_one_clear_error_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "never"
    code, err = train_main([*SMOKE, "--dataset", str(tmp_path / "missing.hdf5"), "--out", str(out)], capsys)
    assert code == 2 and "error: no dataset file at" in err and "Traceback" not in err
    assert not out.exists()
    code, err = train_main([*SMOKE, "--steps", "0", "--out", str(out)], capsys)
    assert code == 2 and "--steps must be > 0" in err and not out.exists()
    code, err = train_main([*SMOKE, "--logger", "tensorbord", "--out", str(out)], capsys)
    assert code == 2 and "--logger must be one or several" in err and not out.exists()
    code, err = train_main([*SMOKE, "--costs", "x_velocity,speed", "--out", str(out)], capsys)
    assert code == 2 and err.strip().count("\n") == 0 and "unknown cost metric 'speed'" in err and not out.exists()
    code, err = train_main([*SMOKE, "--returns", "true", "--method", "bc", "--out", str(out)], capsys)
    assert code == 2 and "--returns true means --method dt, not bc" in err and not out.exists()
    with pytest.raises(SystemExit) as e:  # argparse: usage and exit 2
        train_main(["--env", "ant"], capsys)
    assert e.value.code == 2 and "invalid choice: 'ant'" in capsys.readouterr().err
    for flag, bad in (("--physics", "bullet"), ("--dynamics", "gym")):
        with pytest.raises(SystemExit) as e:
            train_main([*SMOKE, flag, bad, "--out", str(out)], capsys)
        assert e.value.code == 2 and f"invalid choice: '{bad}'" in capsys.readouterr().err and not out.exists()


def test_bad_out_is_refused_before_the_dataset_is_recorded(tmp_path, cli_env, capsys, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    (tmp_path / "afile").write_text("x")
    named = [*SMOKE, "--dataset", "medium"]  # would record hopper medium into the (empty) cache first
    for out, message in [(tmp_path / "afile", "is a file, not a directory"),
                         (tmp_path / "afile" / "run", "is a file, not a directory"),
                         ("/proc/minsubdt-run", "cannot write in /proc")]:
        code, err = train_main([*named, "--out", str(out)], capsys)
        assert code == 2 and message in err and "Traceback" not in err, err
    assert not (tmp_path / "cache").exists()  # nothing recorded


# each bounded setting: a value just outside its range, the range its one error line names, a value on its edge
BOUNDS = [("dropout", 1.0, "in [0, 1)", 0.0), ("eval_episodes", -1, ">= 0", 0), ("weight_decay", -1e-4, ">= 0", 0.0),
          ("grad_clip", 0.0, "> 0", 1e-3), ("discount", 1.5, "in [0, 1]", 1.0), ("iql_expectile", 1.0, "in (0, 1)", 0.5),
          ("cql_alpha", -1.0, ">= 0", 0.0), ("tau", 1.5, "in (0, 1]", 1.0), ("brac_alpha", -0.1, ">= 0", 0.0),
          ("ema_decay", 1.0, "in [0, 1)", 0.0), ("cost_label_noise", 0.5, "in [0, 0.5)", 0.0),
          ("physics_threads", -1, ">= 0", 0), ("devices", -1, ">= 0", 0), ("seed", -1, ">= 0", 0),
          ("dataset_seed", -1, ">= 0", 0), ("dataset_transitions", 0, "> 0", 1), ("rtg_scale", 0.0, "> 0", None),
          ("actor_lr", -1e-3, "> 0", None), ("alpha_max", 0.0, "> 0", None)]


@pytest.mark.parametrize("name,bad,says,edge", BOUNDS)
def test_a_setting_out_of_range_is_one_error_naming_that_setting_and_its_range(name, bad, says, edge):
    """Not one message for several settings ('need --eval-episodes >= 0, 0 <= --dropout < 1, ...'): the one that is
    wrong, its range, and the value given."""
    import dataclasses

    from minsubdt_jax.config import PRESETS, validate

    flag = "--" + name.replace("_", "-")
    with pytest.raises(ValueError) as e:
        validate(dataclasses.replace(PRESETS["smoke"], **{name: bad}))
    assert str(e.value).startswith(f"{flag} must be {says}") and f"got {bad}" in str(e.value), str(e.value)
    validate(dataclasses.replace(PRESETS["smoke"], **{name: edge}))
