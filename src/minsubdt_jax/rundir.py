"""Helpers shared by the command-line programs: resume checks, metric-log truncation, progress bar, and one
clear ``error:`` line (exit 2) for bad input."""

from __future__ import annotations

import json
import os
import sys
from typing import Callable


def check_run_dir(config: dict, out: str, ckpt_dir: str, resume: bool, resumable: tuple[str, ...]) -> None:
    """Refuse to overwrite a run's checkpoints without ``--resume``, and to resume a run whose saved
    ``config.json`` differs from ``config`` in any field outside ``resumable``."""
    cfg_path = os.path.join(out, "config.json")
    has_ckpt = os.path.isdir(ckpt_dir) and any(d.isdigit() for d in os.listdir(ckpt_dir))
    if resume:
        if not os.path.exists(cfg_path) or not has_ckpt:
            raise ValueError(f"--resume: no checkpoint in {out}")
        with open(cfg_path) as f:
            old = json.load(f)
        diff = {k: (old.get(k), v) for k, v in config.items() if k not in resumable and old.get(k) != v}
        if diff:
            raise ValueError(f"--resume: config differs from the checkpointed run in {diff} (old, new)")
    elif has_ckpt:
        raise ValueError(f"{out} already holds checkpoints: pass --resume to continue, or another --out")


def truncate_metrics(path: str, step: int) -> None:
    """Drop metric lines past ``step`` (written after the checkpoint a resumed run restarts from)."""
    if not os.path.exists(path):
        return
    with open(path) as f:
        lines = [ln for ln in f if ln.strip() and json.loads(ln)["step"] <= step]
    with open(path, "w") as f:
        f.writelines(lines)


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
    return 0
