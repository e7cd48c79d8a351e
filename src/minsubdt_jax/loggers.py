"""Where a run's records go besides ``metrics.jsonl`` (which stays the record): TensorBoard and Weights & Biases.

``--logger tensorboard`` writes tensorboardX event files to ``<run dir>/tensorboard``; ``--logger wandb`` logs to
W&B (the optional extra ``pip install 'minsubdt-jax[wandb]'``; ``WANDB_MODE=offline`` keeps it on disk, under
``<run dir>/wandb``). Both take the records of ``metrics.jsonl`` (d3rlpy's logger adapters and
mujoco_playground's optional loggers do the same): a number is a scalar under its key, a list over the models is
one scalar per model, ``key/<method>-s<seed>``, and their mean, ``key/mean``. Only process 0 logs.
"""

from __future__ import annotations

import importlib.util
import os

LOGGERS = ("tensorboard", "wandb")


def logger_names(spec: str | None) -> tuple[str, ...]:
    """The names of ``--logger`` (comma-separated); raises ValueError on an unknown one or a missing package."""
    names = () if not spec else tuple(n.strip() for n in spec.split(","))
    bad = [n for n in names if n not in LOGGERS]
    if bad or len(set(names)) != len(names):
        raise ValueError(f"--logger must be one or several (comma-separated, each once) of {list(LOGGERS)}, got {spec!r}")
    package = {"tensorboard": "tensorboardX", "wandb": "wandb"}
    missing = [n for n in names if importlib.util.find_spec(package[n]) is None]
    if missing:
        raise ValueError(f"--logger {missing[0]} needs the {package[missing[0]]} package: pip install "
                         f"'minsubdt-jax[{missing[0]}]'")
    return names


def scalars(record: dict, labels: list[str] | None = None) -> dict[str, float]:
    """A ``metrics.jsonl`` record as flat scalars (module docstring); ``step`` and the labels are left out. A list
    over the models is tagged ``key/<method>-s<seed>``: the record's own labels, else the run's ``labels``."""
    own = [f"{m}-s{s}" for m, s in zip(record.get("eval_method", []), record.get("eval_seed", []))]
    labels = own or labels or []
    out = {}
    for k, v in record.items():
        if k in ("step", "eval_method", "eval_seed", "final") or isinstance(v, (bool, str)) or v is None:
            continue
        if isinstance(v, (int, float)):
            out[k] = float(v)
        elif isinstance(v, list) and v and all(isinstance(x, (int, float)) for x in v):
            names = labels if len(labels) == len(v) else [str(i) for i in range(len(v))]
            out.update({f"{k}/{n}": float(x) for n, x in zip(names, v)})
            out[f"{k}/mean"] = sum(v) / len(v)
    return out


class Loggers:
    """The loggers of one run: ``log(record)`` and ``close()``."""

    def __init__(self, names: tuple[str, ...], run_dir: str, config: dict, labels: list[str] | None = None):
        self.writers, self.labels = [], labels  # labels: the models', <method>-s<seed>, for every per-model list
        if "tensorboard" in names:
            from tensorboardX import SummaryWriter

            self.writers.append(("tensorboard", SummaryWriter(os.path.join(run_dir, "tensorboard"))))
        if "wandb" in names:
            import wandb

            os.makedirs(run_dir, exist_ok=True)
            run = wandb.init(project=os.environ.get("WANDB_PROJECT", "minsubdt-jax"), dir=run_dir, config=config,
                             name=os.path.basename(os.path.normpath(run_dir)), reinit=True)
            self.writers.append(("wandb", run))

    def log(self, record: dict) -> None:
        values, step = scalars(record, self.labels), int(record["step"])
        for kind, w in self.writers:
            if kind == "tensorboard":
                for k, v in values.items():
                    w.add_scalar(k, v, step)
                w.flush()
            else:
                w.log(values, step=step)

    def close(self) -> None:
        for kind, w in self.writers:
            w.close() if kind == "tensorboard" else w.finish()
