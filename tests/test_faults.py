"""Faults (issue 56): a second writer into a run directory, Ctrl-C, a checkpoint cut, file modes, a cache that
cannot be written, a killed recording, a failed write. Each case is one clear line and leaves nothing
half-written; bad input is tests/test_bad_input.py's."""

import json
import os
import signal
import threading

import pytest

from cli_helpers import SMOKE, train_main


def test_a_second_writer_into_the_same_out_is_one_error_and_writes_nothing(tmp_path, small_dataset_path, capsys):
    """Two trainings into one --out used to both run, interleaving metrics.jsonl and mixing checkpoints. The run
    directory is locked from its first write to its end: while another process holds it, a training into it is
    one error line naming the holder (exit 2) and writes nothing there; once released, it is free again."""
    from minsubdt_jax.rundir import LOCK_FILE, RunLock

    out = tmp_path / "run"
    holder = RunLock()
    holder.acquire(str(out))  # as a running training holds it (its own open of the file: the lock conflicts)
    try:
        code, err = train_main([*SMOKE, "--dataset", small_dataset_path, "--out", str(out)], capsys)
    finally:
        holder.release()
    assert code == 2 and f"is in use by process {os.getpid()}" in err and err.strip().count("\n") == 0
    assert sorted(os.listdir(out)) == [LOCK_FILE]
    again = RunLock()
    again.acquire(str(out))
    again.release()


def test_results_are_always_valid_json():
    """A non-finite value that reaches a record (an evaluation's NaN) is written as null, never as bare NaN."""
    from minsubdt_jax.rundir import json_text

    text = json_text({"a": float("nan"), "b": [1.0, float("inf")], "c": {"d": -float("inf"), "e": 2}})
    assert json.loads(text, parse_constant=lambda c: pytest.fail(f"bare {c}")) == {"a": None, "b": [1.0, None],
                                                                                    "c": {"d": None, "e": 2}}


@pytest.mark.parametrize("umask,mode", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_written_files_respect_the_umask(tmp_path, umask, mode):
    """Run and cache files were created 0600 whatever the umask (mkstemp's mode): they take the umask's."""
    from minsubdt_jax.rundir import write_atomic

    old = os.umask(umask)
    try:
        write_atomic(str(tmp_path / "f.json"), "{}")
    finally:
        os.umask(old)
    assert os.stat(tmp_path / "f.json").st_mode & 0o777 == mode


def test_ctrl_c_stops_after_the_chunks_checkpoint_with_one_line_and_resumes(tmp_path, small_dataset_path, capsys,
                                                                           monkeypatch):
    """Ctrl-C used to print a 42-line traceback. During training it finishes the current chunk and its checkpoint,
    then stops with one line that gives the resume command (exit 130, no results.json); that command finishes the
    run. The key press itself is acknowledged at once (the chunk may take minutes). Here the SIGINT arrives while the first of two 10-step chunks is being logged."""
    from minsubdt_jax.train import parse_args
    from minsubdt_jax.rundir import Interrupted, exit_code
    from minsubdt_jax.train import main, train

    from minsubdt_jax import loop

    out = tmp_path / "run"
    cfg, _ = parse_args([*SMOKE, "--dataset", small_dataset_path, "--out", str(out), "--eval-episodes", "1"])
    moves = []

    class Bar:  # the progress bar: it moves within a chunk (10 pieces of 1 step in the smoke preset's chunk of 10)
        def __getattr__(self, name):
            return moves.append if name == "update" else (lambda *a, **k: None)
    monkeypatch.setattr(loop, "progress", lambda **_: Bar())

    def ctrl_c(step, record):
        if "loss" in record and step == 10:
            os.kill(os.getpid(), signal.SIGINT)

    before = signal.getsignal(signal.SIGINT)  # Python's default, or SIG_IGN in a job started in the background
    with pytest.raises(Interrupted, match=r"at step 10 of 20; resume with: python -m minsubdt_jax.train --config "
                                          r".*config\.json --resume") as e:
        train(cfg, verbose=False, progress_fn=ctrl_c)
    assert sorted(d for d in os.listdir(out / "checkpoints") if d.isdigit()) == ["10"]
    assert not (out / "results.json").exists() and moves == [1] * 10
    assert signal.getsignal(signal.SIGINT) is before  # the handler is given back
    assert "Ctrl-C: stopping after this chunk's checkpoint" in capsys.readouterr().err  # said when pressed

    def stopped():
        raise e.value
    assert exit_code(stopped) == 130
    err = capsys.readouterr().err
    assert err.startswith("interrupted: stopped after the checkpoint") and err.strip().count("\n") == 0
    resume = str(e.value).split("resume with: python -m minsubdt_jax.train ")[1].split()
    assert main(resume) == 0
    assert json.loads((out / "results.json").read_text())["train"]["steps_this_run"] == 10


def test_a_checkpoint_is_on_disk_when_its_save_returns(tmp_path):
    """The run's and the SAC trainer's checkpoints are written synchronously (``rundir.checkpoint_manager``).
    Orbax's asynchronous commit gives up after a timeout counted from the save: a Table 1 unit whose process was
    stopped for ~10 minutes died at its next checkpoint ("ChainedFuture completed 2/3 futures but timed out"), as a
    run on a laptop that sleeps would. The saved step is there for another reader at once, before any wait (with
    the asynchronous manager it was not, 5 times of 5)."""
    import numpy as np
    import orbax.checkpoint as ocp

    from minsubdt_jax.rundir import checkpoint_manager

    mngr = checkpoint_manager(str(tmp_path / "c"), keep=2)
    mngr.save(3, args=ocp.args.StandardSave({"x": np.arange(100_000.0)}))
    assert ocp.CheckpointManager(str(tmp_path / "c")).latest_step() == 3


def _cached(small_dataset, monkeypatch, tmp_path):
    """A cached 'medium' recording of the small dataset's shape (as resolve_dataset names its cache files)."""
    from minsubdt_jax.data import save_d4rl
    from minsubdt_jax.data.named import dataset_path

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    path = dataset_path("hopper", "medium", 2000, 60, 0, "mujoco")
    os.makedirs(os.path.dirname(path))
    save_d4rl(small_dataset, path, env="hopper", dynamics="brax", physics="mujoco")
    return path


def test_a_cached_dataset_loads_from_a_cache_that_cannot_be_written(small_dataset, monkeypatch, tmp_path):
    """A read-only cache that holds the dataset used to be a 33-line traceback (the lock beside the file could not
    be created). Reading a complete cached file takes no lock. (As root a chmod does not stop writes, so the
    unwritable folder is played by a lock that fails as one on a read-only file system does.)"""
    from minsubdt_jax.data import named

    path = _cached(small_dataset, monkeypatch, tmp_path)

    def read_only(*_a, **_k):
        raise PermissionError(30, "Read-only file system")
    monkeypatch.setattr(named, "_lock", read_only)
    monkeypatch.setattr(named.os, "remove", read_only)
    f = named.resolve_dataset("hopper", "medium", transitions=2000, horizon=60, verbose=False, physics="mujoco")
    assert f.path == path and f.data.num_trajectories == small_dataset.num_trajectories


def test_a_killed_recordings_temporary_file_is_removed_when_no_one_records(small_dataset, monkeypatch, tmp_path):
    """A killed recording left its `<name>.*.tmp` forever. It is removed the next time the dataset is asked for and
    no process holds its recording lock; while one does (a live recording's file), it is kept."""
    import fcntl

    from minsubdt_jax.data import named

    path = _cached(small_dataset, monkeypatch, tmp_path)
    orphan = path + ".k1ll3d.tmp"
    open(orphan, "w").write("half a file")
    load = threading.Thread(target=named.resolve_dataset, args=("hopper", "medium"), daemon=True,
                            kwargs=dict(transitions=2000, horizon=60, verbose=False, physics="mujoco"))
    with open(path + ".lock", "a") as held:  # a recording in progress
        fcntl.flock(held, fcntl.LOCK_EX)
        load.start()
        load.join(timeout=60)  # a complete file loads without waiting for the lock
        assert not load.is_alive() and os.path.exists(orphan)
        fcntl.flock(held, fcntl.LOCK_UN)
    named.resolve_dataset("hopper", "medium", transitions=2000, horizon=60, verbose=False, physics="mujoco")
    assert not os.path.exists(orphan) and os.path.exists(path)


def test_a_resume_never_changes_the_cost_metrics_a_run_trains_on(tmp_path, small_dataset_path, capsys):
    """A run trained through the library on a CostMetric of one's own, resumed from the CLI, went on silently with
    the default metrics (config.json said costs: null). The run records its metrics; a resume on others is one
    error line, and through the library with the same metrics it goes on."""
    import dataclasses

    from minsubdt_jax.train import parse_args
    from minsubdt_jax.costs import CostMetric
    from minsubdt_jax.train import train

    lean = CostMetric("lean", lambda obs, act: abs(obs[..., 1]), lo=0.0, hi=0.5)
    out = tmp_path / "own"
    cfg, _ = parse_args([*SMOKE, "--dataset", small_dataset_path, "--out", str(out), "--eval-episodes", "0",
                         "--steps", "10"])
    train(cfg, verbose=False, metrics=["x_velocity", lean])
    saved = json.loads((out / "cost_metrics.json").read_text())
    assert [m["name"] for m in saved] == ["x_velocity", "lean"]
    code, err = train_main([*SMOKE, "--dataset", small_dataset_path, "--out", str(out), "--eval-episodes", "0",
                       "--steps", "20", "--resume"], capsys)
    assert code == 2 and "trained on the cost metrics x_velocity, lean" in err and err.strip().count("\n") == 0
    assert sorted(d for d in os.listdir(out / "checkpoints") if d.isdigit()) == ["10"]  # nothing trained
    res = train(dataclasses.replace(cfg, steps=20), resume=True, verbose=False, metrics=["x_velocity", lean])
    assert res["train"]["steps"] == 20 and [m["name"] for m in res["dataset"]["cost_metrics"]] == ["x_velocity", "lean"]


def test_a_failed_write_leaves_no_file_and_is_one_line(tmp_path, monkeypatch, capsys):
    """A full disk (or a folder that cannot be written) during a write: no partial or temporary file is left
    behind, the old file is kept whole, and the command says one line with the system's reason (exit 2)."""
    from minsubdt_jax import rundir

    target = tmp_path / "results.json"
    target.write_text('{"old": 1}')

    def full(*_a):
        raise OSError(28, "No space left on device", str(target))
    monkeypatch.setattr(rundir.os, "replace", full)
    assert rundir.exit_code(lambda: rundir.write_atomic(str(target), '{"new": 2}')) == 2
    err = capsys.readouterr().err
    assert err == f"error: No space left on device: {target}\n"
    assert sorted(os.listdir(tmp_path)) == ["results.json"] and target.read_text() == '{"old": 1}'


def test_the_progress_bar_moves_within_a_chunk_and_the_pieces_train_the_same_steps():
    """The bar moved once per chunk (the `cpu` preset's first update came after minutes). A chunk now runs as ~10
    dispatches of a tenth of it, and the bar moves after each; the pieces are the same steps as one scan (the state
    carries the rng and the step): the parameters are identical bit for bit, here DT over 20 steps as one scan and as
    ten of 2. AWR's chunk (one iteration, not a scan of steps) stays whole."""
    import dataclasses

    import jax
    import numpy as np

    from minsubdt_jax.agents import make_agent
    from minsubdt_jax.agents.base import init_state, make_optimizer, make_train_chunk, merge_losses, piece_steps
    from minsubdt_jax.config import PRESETS
    from minsubdt_jax.data import Trajectories, sampler_data

    assert [piece_steps(n, False) for n in (500, 2000, 10, 7, 1)] == [50, 200, 1, 1, 1]
    assert piece_steps(1200, True) == 1200
    rng = np.random.default_rng(0)
    n, T, obs, act = 8, 30, 11, 3
    ds = Trajectories(rng.normal(size=(n, T, obs)).astype(np.float32), rng.uniform(-1, 1, (n, T, act)).astype(np.float32),
                      np.zeros((n, T), np.float32), np.full(n, T, np.int32), np.zeros(n, bool))
    data = sampler_data(ds, rng.normal(size=(n, T)), np.zeros(obs, np.float32), np.ones(obs, np.float32))
    cfg = dataclasses.replace(PRESETS["smoke"], ema_decay=0.9)
    agent, tx = make_agent("dt", cfg, obs, act, T), make_optimizer(cfg)
    whole, losses = make_train_chunk(agent, tx, 8, 20, ema_decay=0.9)(init_state(agent, tx, jax.random.PRNGKey(0),
                                                                                  ema=True), data)
    piece, state, pieces = make_train_chunk(agent, tx, 8, 2, ema_decay=0.9), init_state(agent, tx, jax.random.PRNGKey(0),
                                                                                        ema=True), []
    for _ in range(10):
        state, out = piece(state, data)
        pieces.append(out)
    joined, _ = merge_losses(pieces)
    assert np.array_equal(np.asarray(joined), np.asarray(losses))
    for a, b in zip(jax.tree.leaves(whole), jax.tree.leaves(state)):
        assert np.array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.slow
def test_a_recording_onto_a_full_disk_is_one_error_line_and_leaves_no_file(tmp_path):
    """A disk that filled up mid-write crashed the interpreter (exit 139: h5py's close wrote again into the full
    file after a screen of OSError tracebacks) and left a ``*.tmp`` in the cache. A file-size limit (``ulimit -f``,
    EFBIG, as a full disk's ENOSPC) stands in for the full disk: one ``error:`` line, exit 2, no dataset and no
    temporary file."""
    import resource
    import subprocess
    import sys

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (1 << 20, 1 << 20))  # 1 MiB; the recording is ~2 MiB

    env = dict(os.environ, XDG_CACHE_HOME=str(tmp_path), JAX_ENABLE_COMPILATION_CACHE="false")
    p = subprocess.run([sys.executable, "-m", "minsubdt_jax.data", "--env", "hopper", "--dataset", "random",
                        "--transitions", "20000"], env=env, capture_output=True, text=True, preexec_fn=limit,
                       timeout=300)
    assert p.returncode == 2, p.stderr[-2000:]
    lines = [x for x in p.stderr.strip().splitlines() if not x.startswith("hopper/random:")]  # its progress bar
    assert len(lines) == 1 and lines[0].startswith("error: File too large: ") and "hopper-random" in lines[0], \
        p.stderr[-2000:]
    left = [f for _, _, fs in os.walk(tmp_path) for f in fs if f.endswith((".hdf5", ".tmp"))]
    assert left == []
