"""``python -m minsubdt_jax.data --env walker --dataset medium``: record a named dataset into the cache."""

from __future__ import annotations

import argparse
import os
import sys
import time

from ..caches import enable_compilation_cache
from ..envs import ENVS
from ..rundir import exit_code
from .dataset import DatasetError
from .named import DEFAULT_TRANSITIONS, NAMED_DATASETS, dataset_path, resolve_dataset, summary_line


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m minsubdt_jax.data",
                                description="Record a D4RL-style dataset in MJX from the committed behaviour policies.")
    p.add_argument("--env", required=True, choices=tuple(ENVS))
    p.add_argument("--dataset", required=True, choices=NAMED_DATASETS)
    p.add_argument("--transitions", type=int, default=DEFAULT_TRANSITIONS,
                   help=f"at least this many transitions, in whole episodes (default {DEFAULT_TRANSITIONS}; "
                        "D4RL: 1000000); medium-expert holds twice this")
    p.add_argument("--horizon", type=int, default=1000, help="episode length before a time-out")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--force", action="store_true", help="record again even if the cache holds the file")
    a = p.parse_args(argv)
    enable_compilation_cache()
    return exit_code(lambda: record(a.env, a.dataset, a.transitions, a.horizon, a.seed, a.force))


def record(env: str, dataset: str, transitions: int, horizon: int, seed: int, force: bool) -> None:
    if transitions < 1 or horizon < 1:
        raise DatasetError(f"transitions and horizon must be >= 1, got {transitions} and {horizon}")
    path = dataset_path(env, dataset, transitions, horizon, seed)
    if force and os.path.exists(path):
        os.remove(path)
    cached = os.path.exists(path)
    t0 = time.time()
    f = resolve_dataset(env, dataset, transitions=transitions, horizon=horizon, seed=seed)
    if cached:
        print(summary_line(env, dataset, f.data, time.time() - t0, horizon) + f" (cached: {f.path})")

if __name__ == "__main__":
    sys.exit(main())
