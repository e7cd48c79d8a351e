"""Named datasets made in MJX and cached on disk.

Until the behaviour-policy datasets exist, the one named dataset is ``random``: uniformly random actions,
as D4RL's random datasets. Files are cached under ``$XDG_CACHE_HOME/minsubdt_jax/datasets`` (else
``~/.cache/...``), one per (env, name, episodes, horizon, seed), and generated on first use.
"""

from __future__ import annotations

import os
import time

import jax
import numpy as np

from ..envs import env_spec, make_rollout, random_policy
from .d4rl import load_d4rl, save_d4rl
from .dataset import DatasetError, Trajectories, from_padded

NAMED_DATASETS = ("random",)


def cache_dir() -> str:
    """``$XDG_CACHE_HOME/minsubdt_jax`` or ``~/.cache/minsubdt_jax``."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "minsubdt_jax")


def generate_random(env: str, episodes: int, horizon: int, seed: int) -> Trajectories:
    """``episodes`` episodes of uniformly random actions in batched MJX, each at most ``horizon`` steps."""
    spec = env_spec(env)
    run = make_rollout(env, random_policy, episodes, horizon)
    ro = jax.device_get(run(np.zeros(spec.act_dim, np.float32), (), jax.random.PRNGKey(seed)))
    return from_padded(ro.observations, ro.actions, ro.rewards, ro.lengths, ro.terminated)


def resolve_dataset(env: str, dataset: str, *, episodes: int = 1000, horizon: int = 1000, seed: int = 0,
                    verbose: bool = True) -> tuple[Trajectories, str]:
    """Load ``dataset``: a path to a D4RL-layout hdf5 file, or a name in ``NAMED_DATASETS`` (generated into
    the cache on first use with ``episodes``, ``horizon``, ``seed``). Returns the dataset and its file path."""
    if os.sep in dataset or dataset.endswith((".hdf5", ".h5")) or os.path.exists(dataset):
        return load_d4rl(dataset), dataset
    if dataset not in NAMED_DATASETS:
        raise DatasetError(f"unknown dataset {dataset!r}: give a path to a D4RL-layout .hdf5 file or one of "
                           f"{list(NAMED_DATASETS)}")
    name = env_spec(env).name
    path = os.path.join(cache_dir(), "datasets", f"{name}-{dataset}-e{episodes}-h{horizon}-s{seed}.hdf5")
    if not os.path.exists(path):
        if verbose:
            print(f"generating {name}/{dataset} ({episodes} episodes, horizon {horizon}) in MJX -> {path}", flush=True)
        t0 = time.time()
        data = generate_random(name, episodes, horizon, seed)
        save_d4rl(data, path)
        if verbose:
            print(f"  {data.num_trajectories} episodes, {data.num_transitions} transitions, return "
                  f"{data.returns.mean():.1f} ± {data.returns.std():.1f} ({time.time() - t0:.0f} s)", flush=True)
    return load_d4rl(path), path
