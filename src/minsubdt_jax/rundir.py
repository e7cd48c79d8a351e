"""Helpers shared by the command-line programs: run-directory checks before anything is written, resume checks,
atomic writes, the metric log (read, truncate, plot), progress bar, and one clear ``error:`` line (exit 2) for
bad input."""

from __future__ import annotations

import fcntl
import json
import math
import os
import signal
import socket
import sys
import tempfile
import threading
from typing import Callable


from .atomic import write_atomic  # noqa: F401  (the run's writes; re-exported)

DATASET_FILE = "dataset.json"  # the identity (content hash) of the data a run trains on


def check_run_dir(config: dict, out: str, ckpt_dir: str, resume: bool, resumable: tuple[str, ...],
                  defaults: dict | None = None) -> None:
    """Before anything is written or recorded: ``out`` must be a directory we can create and write in; refuse to
    overwrite a run's checkpoints without ``--resume``; refuse to resume a run whose saved ``config.json``
    differs from ``config`` in any field outside ``resumable``, or to a ``steps`` below its last checkpoint. A
    field the saved config lacks (a run of an older version) counts as its value in ``defaults``."""
    check_writable_dir(out)
    cfg_path = os.path.join(out, "config.json")
    steps = checkpoint_steps(ckpt_dir)
    if resume:
        if not os.path.exists(cfg_path) or not steps:
            raise ValueError(f"--resume: no checkpoint in {out}")
        with open(cfg_path) as f:
            old = json.load(f)
        old = {**(defaults or {}), **old}
        diff = {k: (old.get(k), v) for k, v in config.items() if k not in resumable and old.get(k) != v}
        if diff:
            raise ValueError(f"--resume: config differs from the checkpointed run in {diff} (old, new)")
        if "steps" in config and config["steps"] < max(steps):
            raise ValueError(f"--resume: --steps {config['steps']} is below the run's last checkpoint, step "
                             f"{max(steps)}; give --steps {max(steps)} or more")
    elif steps:
        raise ValueError(f"{out} already holds checkpoints: pass --resume to continue, or another --out")


def check_same_data(out: str, sha256: str, resume: bool, what: str = "--resume") -> None:
    """On resume (or a run read back, ``what`` its name in the message), the data must be the data the run started
    on (its content hash in ``dataset.json``)."""
    if not resume:
        return
    path = os.path.join(out, DATASET_FILE)
    if not os.path.exists(path):
        raise ValueError(f"{what}: {out} records no dataset hash ({DATASET_FILE}; written by an older version), "
                         f"so the same data cannot be checked: start a new run")
    with open(path) as f:
        old = json.load(f)["sha256"]
    if old != sha256:
        raise ValueError(f"{what}: the dataset differs from the one the run started on (sha256 {old[:12]}…, now "
                         f"{sha256[:12]}…)")


# the cost metrics a run trains on (a user's own ones cannot be named in --costs)
COST_METRICS_FILE = "cost_metrics.json"


def check_same_metrics(out: str, records: list[dict], resume: bool, what: str = "--resume") -> None:
    """On resume (or a run read back, ``what`` its name in the message), the cost metrics (their
    ``CostMetric.record()``) must be those the run started on: a run trained through the library on a metric of
    one's own, resumed from the CLI, would go on with the defaults."""
    path = os.path.join(out, COST_METRICS_FILE)
    if not resume or not os.path.exists(path):  # a run of an older version records none
        return
    with open(path) as f:
        saved = json.load(f)
    if saved != records:
        names = lambda rs: ", ".join(r["name"] for r in rs)  # noqa: E731
        raise ValueError(f"{what}: the run trained on the cost metrics {names(saved)} ({COST_METRICS_FILE}), not on "
                         f"{names(records)}; a metric of one's own is given again with train(..., metrics=[...]), "
                         f"which the command line cannot do")


def checkpoint_steps(ckpt_dir: str) -> list[int]:
    """Steps of the checkpoints in ``ckpt_dir`` (orbax writes one numbered folder each)."""
    if not os.path.isdir(ckpt_dir):
        return []
    return [int(d) for d in os.listdir(ckpt_dir) if d.isdigit()]


def checkpoint_manager(ckpt_dir: str, keep: int):
    """The orbax manager of a run's checkpoints (the agents' and the SAC trainer's), keeping the last ``keep``.
    Synchronous: a save is on disk when it returns. Orbax's asynchronous commit gives up after its timeout
    (``AsyncOptions.timeout_secs``) counted from the save, so a machine suspended for longer (a laptop asleep, a
    stopped job) lost the run at its next checkpoint; these states are small enough to write in place."""
    import orbax.checkpoint as ocp

    return ocp.CheckpointManager(ckpt_dir, options=ocp.CheckpointManagerOptions(max_to_keep=keep, create=True,
                                                                                enable_async_checkpointing=False))


def check_writable_dir(out: str) -> None:
    """``out`` is, or can be made, a directory we can write in: checked by creating (and removing) a temporary
    directory in it or in its nearest existing ancestor, which changes nothing."""
    if os.path.exists(out) and not os.path.isdir(out):
        raise ValueError(f"--out {out} is a file, not a directory")
    parent = os.path.abspath(out)
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent):
        raise ValueError(f"--out {out}: {parent} is a file, not a directory")
    try:
        os.rmdir(tempfile.mkdtemp(dir=parent, prefix=".write-check-"))
    except OSError as e:
        raise ValueError(f"--out {out}: cannot write in {parent} ({e.strerror or e})") from None


LOCK_FILE = ".lock"  # in a run directory: held (fcntl) by the one process writing it


class RunLock:
    """One writer per run directory: an exclusive ``fcntl.flock`` on ``<out>/.lock``, held from the first write of
    a run to its end (the kernel drops it when the process dies, so a killed run leaves no stale lock)."""

    def __init__(self):
        self.fd = None

    def acquire(self, out: str) -> None:
        """Take the lock, or raise ValueError naming the process that holds it (nothing written)."""
        os.makedirs(out, exist_ok=True)
        fd = os.open(os.path.join(out, LOCK_FILE), os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 256).decode(errors="replace").strip() or "another process"
            os.close(fd)
            raise ValueError(f"--out {out} is in use by {holder}: one run writes a run directory at a time; wait "
                             f"for it to end, or give another --out") from None
        os.ftruncate(fd, 0)
        os.write(fd, f"process {os.getpid()} on {socket.gethostname()}".encode())
        self.fd = fd

    def release(self) -> None:
        if self.fd is not None:
            fcntl.flock(self.fd, fcntl.LOCK_UN)
            os.close(self.fd)
            self.fd = None


def json_text(obj, **kw) -> str:
    """``json.dumps`` whose output is always valid JSON: a non-finite float (NaN, inf) becomes ``null``."""
    def clean(x):
        if isinstance(x, float):
            return x if math.isfinite(x) else None
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v) for v in x]
        return x

    return json.dumps(clean(obj), allow_nan=False, **kw)


def per_model(record: dict, what: str = "eval"):
    """A run record's list over its models: ``results.json``'s ``eval_per_model`` (``what="eval"``) or a
    ``metrics.jsonl`` record's ``loss_per_model`` (``"loss"``); runs written before the rename name them
    ``*_per_seed``. None where the record has none."""
    return record.get(f"{what}_per_model", record.get(f"{what}_per_seed"))


def read_metrics(path: str) -> list[dict]:
    """The records of a ``metrics.jsonl``; a torn last line (a kill while it was written) is dropped, a damaged
    line before it is an error."""
    if not os.path.exists(path):
        return []
    with open(path) as f:
        lines = [ln for ln in f.read().split("\n") if ln.strip()]
    rows = []
    for i, ln in enumerate(lines):
        try:
            rows.append(json.loads(ln))
        except json.JSONDecodeError as e:
            if i == len(lines) - 1:
                break
            raise ValueError(f"{path}: line {i + 1} is not JSON ({e}); the log is damaged") from None
    return rows


def truncate_metrics(path: str, step: int) -> None:
    """Drop metric lines past ``step`` (written after the checkpoint a resumed run restarts from), and a torn last
    line; the log is replaced atomically."""
    if not os.path.exists(path):
        return
    rows = [r for r in read_metrics(path) if r["step"] <= step]
    write_atomic(path, "".join(json.dumps(r) + "\n" for r in rows))


def progress(total: int, initial: int, disable: bool, unit: str = "step"):
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, disable=disable, unit=unit, dynamic_ncols=True, file=sys.stdout,
                mininterval=1.0)


def exit_code(run: Callable[[], object]) -> int:
    """Run a command's body: 0 on success; on bad input (``ValueError``, which ``DatasetError`` is) one
    ``error:`` line on stderr, no traceback, and 2."""
    try:
        run()
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except Interrupted as e:
        print(f"interrupted: {e}", file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        print("interrupted (Ctrl-C)", file=sys.stderr)
        return 130
    except OSError as e:  # a full disk, a folder that cannot be written: what the system said, and where
        print(f"error: {e.strerror or e}" + (f": {e.filename}" if e.filename else ""), file=sys.stderr)
        return 2
    return 0


class Interrupted(Exception):
    """Ctrl-C during a run, after the checkpoint it stopped at: the message says how to resume."""


class InterruptFlag:
    """From its creation until :meth:`restore`, the first Ctrl-C (SIGINT) sets :attr:`raised` instead of raising,
    so a training loop can stop after its current chunk's checkpoint; a second Ctrl-C raises at once. Outside the
    main thread (where no handler can be set) it never sets."""

    def __init__(self):
        self.raised = False
        self.previous = None
        if threading.current_thread() is threading.main_thread():
            self.previous = signal.signal(signal.SIGINT, self._handle)

    def _handle(self, signum, frame):
        self.raised = True
        signal.signal(signal.SIGINT, self.previous)
        print("\nCtrl-C: stopping after this chunk's checkpoint (Ctrl-C again stops now, losing the chunk)",
              file=sys.stderr, flush=True)

    def restore(self) -> None:
        if self.previous is not None:
            signal.signal(signal.SIGINT, self.previous)
            self.previous = None


def model_labels(record: dict, n: int) -> list[str]:
    """The models' labels in an evaluation record of ``metrics.jsonl``: their method (``dataset/method`` in a
    program over several datasets), or ``run`` for an older record without them."""
    methods = record.get("eval_method") or ["run"] * n
    return [f"{d}/{m}" for d, m in zip(record["eval_dataset"], methods)] if "eval_dataset" in record else methods
