"""D4RL hdf5 files: ``observations, actions, rewards, terminals, timeouts`` (+ optional ``infos/...``)."""

from __future__ import annotations

import os

import h5py
import numpy as np

from .dataset import REQUIRED_KEYS, DatasetError, Trajectories, from_flat


def load_d4rl(path) -> Trajectories:
    """Load a D4RL-layout hdf5 file into :class:`Trajectories` (episodes split on terminals | timeouts).

    Raises:
      DatasetError: no such file, not an hdf5 file, or contents that fail validation (see ``from_flat``).
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise DatasetError(f"no dataset file at {path}")
    try:
        with h5py.File(path, "r") as f:
            arrays = {k: f[k][()] for k in REQUIRED_KEYS if k in f}
    except OSError as e:
        raise DatasetError(f"{path}: not a readable hdf5 file ({e})") from None
    return from_flat(arrays, source=path)


def save_d4rl(dataset: Trajectories, path, infos: dict[str, np.ndarray] | None = None) -> None:
    """Write ``dataset`` in the D4RL flat layout; ``infos`` (flat per-step arrays) go under ``infos/``.

    Written to a temporary name and renamed, so a crash never leaves a half-written file behind.
    """
    path = os.fspath(path)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    tmp = path + ".tmp"
    with h5py.File(tmp, "w") as f:
        for k, v in dataset.to_flat().items():
            f.create_dataset(k, data=v, compression="gzip", compression_opts=1)
        for k, v in (infos or {}).items():
            f.create_dataset(f"infos/{k}", data=v, compression="gzip", compression_opts=1)
    os.replace(tmp, path)
