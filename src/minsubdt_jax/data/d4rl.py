"""D4RL hdf5 files: ``observations, actions, rewards, terminals, timeouts`` (+ optional ``infos/...``).

Files this package writes carry two root attributes: ``sha256``, the content hash of the episodes
(:meth:`Trajectories.sha256`), verified on every load (HDF5 reads a lost chunk as zeros, so a damaged file
can otherwise load without error), and ``env``, the environment the data was recorded in. Files from
elsewhere (D4RL's own) have neither and load unverified. D4RL v0 files have no ``timeouts``: they are inferred
from the time limit (``horizon``) and the load says so (:attr:`DatasetFile.timeouts_inferred`).
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass

import h5py
import numpy as np

from .dataset import REQUIRED_KEYS, DatasetError, Trajectories, checksum, from_flat, infer_timeouts


@dataclass(frozen=True)
class DatasetFile:
    """A dataset as loaded from its file.

    Attributes:
      data: the episodes.
      path: the file.
      sha256: content hash of ``data`` (:meth:`Trajectories.sha256`): what a run records and a resume compares.
      env: the environment named in the file (files written here), else ``None``.
      timeouts_inferred: the file had no ``timeouts`` (D4RL v0); they were inferred from the horizon.
      dropped_transitions: transitions after the file's last episode end (an unfinished episode), not loaded.
    """

    data: Trajectories
    path: str
    sha256: str
    env: str | None = None
    timeouts_inferred: bool = False
    dropped_transitions: int = 0


def open_d4rl(path, horizon: int = 1000) -> DatasetFile:
    """Load and check a D4RL-layout hdf5 file (episodes split on ``terminals | timeouts``).

    Args:
      path: the file.
      horizon: the time limit, used only for a file without ``timeouts`` (D4RL v0).
    Raises:
      DatasetError: no such file, not a readable hdf5 file (damaged included), a checksum that does not match
        the contents, or contents that fail validation (see :func:`~minsubdt_jax.data.dataset.from_flat`).
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise DatasetError(f"no dataset file at {path}")
    try:
        with h5py.File(path, "r") as f:
            arrays = {k: f[k][()] for k in REQUIRED_KEYS if k in f}
            stored = _attr(f, "sha256")
            env = _attr(f, "env")
    except (OSError, RuntimeError, KeyError, ValueError, TypeError) as e:  # h5py's errors for damaged files
        raise DatasetError(f"{path}: not a readable hdf5 file ({type(e).__name__}: {e})") from None
    inferred = "timeouts" not in arrays and "terminals" in arrays
    if inferred:
        arrays["timeouts"] = infer_timeouts(arrays["terminals"], horizon)
    data = from_flat(arrays, source=path)
    digest = data.sha256()
    if stored is not None and stored != digest:
        raise DatasetError(f"{path}: the file is damaged: its contents do not match the checksum it was written "
                           f"with (sha256 {stored[:12]}…, read {digest[:12]}…)")
    return DatasetFile(data, path, digest, env, inferred, len(arrays["rewards"]) - data.num_transitions)


def load_d4rl(path, horizon: int = 1000) -> Trajectories:
    """The episodes of a D4RL-layout hdf5 file (:func:`open_d4rl`, which also gives the hash and provenance)."""
    return open_d4rl(path, horizon).data


def save_d4rl(dataset: Trajectories, path, infos: dict[str, np.ndarray] | None = None, env: str | None = None) -> str:
    """Write ``dataset`` in the D4RL flat layout with its checksum (and ``env``); ``infos`` (flat per-step
    arrays) go under ``infos/``, with their own checksum. Returns the content hash.

    Written to a temporary file of its own (unique per writer) and renamed into place, so neither a crash nor a
    concurrent writer of the same path ever leaves a partial file under ``path``.
    """
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    flat = dataset.to_flat()
    digest = dataset.sha256()
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=os.path.basename(path) + ".", suffix=".tmp")
    os.close(fd)
    try:
        with h5py.File(tmp, "w") as f:
            for k, v in flat.items():
                f.create_dataset(k, data=v, compression="gzip", compression_opts=1)
            for k, v in (infos or {}).items():
                f.create_dataset(f"infos/{k}", data=v, compression="gzip", compression_opts=1)
            f.attrs["sha256"] = digest
            if infos:
                f.attrs["infos_sha256"] = checksum(infos)
            if env is not None:
                f.attrs["env"] = env
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise
    return digest


def read_infos(path) -> dict[str, np.ndarray]:
    """The ``infos/`` arrays of a file written by :func:`save_d4rl`, checked against their checksum."""
    path = os.fspath(path)
    try:
        with h5py.File(path, "r") as f:
            infos = {k: f["infos"][k][()] for k in f["infos"]} if "infos" in f else {}
            stored = _attr(f, "infos_sha256")
    except (OSError, RuntimeError, KeyError, ValueError, TypeError) as e:
        raise DatasetError(f"{path}: not a readable hdf5 file ({type(e).__name__}: {e})") from None
    if stored is not None and stored != checksum(infos):
        raise DatasetError(f"{path}: the file is damaged: its infos do not match the checksum they were written with")
    return infos


def _attr(f: h5py.File, name: str) -> str | None:
    v = f.attrs.get(name)
    return None if v is None else (v.decode() if isinstance(v, bytes) else str(v))
