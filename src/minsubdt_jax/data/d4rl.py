"""D4RL hdf5 files: ``observations, actions, rewards, terminals, timeouts`` (+ optional ``infos/...``).

Files this package writes carry root attributes: ``sha256``, the content hash of the episodes
(:meth:`Trajectories.sha256`), verified on every load (HDF5 reads a lost chunk as zeros, so a damaged file
can otherwise load without error), ``env``, the environment the data was recorded in, and ``dynamics`` and
``physics``, the env rules and the backend that recorded it (:mod:`minsubdt_jax.envs`). Files from elsewhere
(D4RL's own) have none of them and load unverified; :func:`file_dynamics` tells which dynamics such a file's data
came from. D4RL v0 files have no ``timeouts``: they are inferred
from the time limit (``horizon``) and the load says so (:attr:`DatasetFile.timeouts_inferred`).
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass

import h5py
import numpy as np

from ..atomic import atomic_path
from ..envs import dynamics_report
from ..envs.check import NEITHER
from ..envs.rules import check_dynamics_name
from .dataset import REQUIRED_KEYS, DatasetError, Trajectories, checksum, from_flat, infer_timeouts


@dataclass(frozen=True)
class DatasetFile:
    """A dataset as loaded from its file.

    Attributes:
      data: the episodes.
      path: the file.
      sha256: content hash of ``data`` (:meth:`Trajectories.sha256`): what a run records and a resume compares.
      env: the environment named in the file (files written here), else ``None``.
      dynamics, physics: the env rules and the physics backend named in the file (files written here; files
        written before these were recorded name neither, and are ``brax`` dynamics in MJX), else ``None``.
      timeouts_inferred: the file had no ``timeouts`` (D4RL v0); they were inferred from the horizon.
      dropped_transitions: transitions after the file's last episode end (an unfinished episode), not loaded.
      references: ``(random, expert, source)`` returns of the dataset's own (a Minari dataset's metadata), which its
        scores normalise with instead of the dynamics' (:func:`minsubdt_jax.references.references_for`), else None.
    """

    data: Trajectories
    path: str
    sha256: str
    env: str | None = None
    timeouts_inferred: bool = False
    dropped_transitions: int = 0
    dynamics: str | None = None
    physics: str | None = None
    references: tuple | None = None


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
            dynamics, physics = _attr(f, "dynamics"), _attr(f, "physics")
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
    if env is not None and dynamics is None:  # recorded here before dynamics were named: brax's, in MJX
        dynamics, physics = "brax", "mjx"
    return DatasetFile(data, path, digest, env, inferred, len(arrays["rewards"]) - data.num_transitions, dynamics,
                       physics)


def load_d4rl(path, horizon: int = 1000) -> Trajectories:
    """The episodes of a D4RL-layout hdf5 file (:func:`open_d4rl`, which also gives the hash and provenance)."""
    return open_d4rl(path, horizon).data


def save_d4rl(dataset: Trajectories, path, infos: dict[str, np.ndarray] | None = None, env: str | None = None,
              dynamics: str | None = None, physics: str | None = None) -> str:
    """Write ``dataset`` in the D4RL flat layout with its checksum (and ``env``, ``dynamics``, ``physics`` when
    given); ``infos`` (flat per-step arrays) go under ``infos/``, with their own checksum. Returns the content hash.

    Written to a temporary file of its own (unique per writer) and renamed into place, so neither a crash nor a
    concurrent writer of the same path ever leaves a partial file under ``path``.
    """
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    flat = dataset.to_flat()
    digest = dataset.sha256()
    # built in memory, then written by Python: a write that fails (a full disk) is one OSError here and the
    # temporary file is removed; h5py writing into the file itself wrote again from its close and crashed (exit 139)
    with h5py.File(io.BytesIO(), "w") as f:
        for k, v in flat.items():
            f.create_dataset(k, data=v, compression="gzip", compression_opts=1)
        for k, v in (infos or {}).items():
            f.create_dataset(f"infos/{k}", data=v, compression="gzip", compression_opts=1)
        f.attrs["sha256"] = digest
        if infos:
            f.attrs["infos_sha256"] = checksum(infos)
        for name, value in (("env", env), ("dynamics", dynamics), ("physics", physics)):
            if value is not None:
                f.attrs[name] = value
        f.flush()
        image = f.id.get_file_image()
    try:
        with atomic_path(path) as tmp, open(tmp, "wb") as out:
            out.write(image)
    except OSError as e:  # what the system said, about the file the user asked for
        raise OSError(e.errno, e.strerror, path) from None
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


def file_dynamics(f: DatasetFile, env: str, dynamics: str | None = None) -> tuple[str, dict]:
    """``(dynamics, how)``: the env rules to evaluate the data of ``f`` in, and how that was decided.

    ``dynamics`` given wins. A file of ours names its own. A file from elsewhere that records physics states
    (``infos/qpos``, ``infos/qvel``; D4RL v2) is replayed under each dynamics (:func:`minsubdt_jax.envs.dynamics_report`)
    and gets the one that reproduces it; one without them is taken to be D4RL's (gym's rules)."""
    if dynamics is not None:
        return check_dynamics_name(dynamics), {"how": "given"}
    if f.dynamics is not None:
        return f.dynamics, {"how": "named by the Minari dataset (its env spec, or our export's metadata)"
                            if f.path.startswith("minari:") else "recorded in the file"}
    if f.path.startswith("minari:"):  # open_minari reads the dynamics from the env spec where it can
        raise DatasetError(f"{f.path} names no dynamics we serve: pass --dynamics brax, d4rl or v5")
    infos = read_infos(f.path)  # a damaged file raises here: no fallback
    if "qpos" not in infos or "qvel" not in infos:
        return "d4rl", {"how": "a D4RL-layout file without physics states: D4RL's (gym's) dynamics assumed"}
    report = replay_report(f, env, infos=infos)
    if report["best"] == NEITHER:
        raise DatasetError(f"{f.path}: no dynamics reproduces its recorded transitions (" + ", ".join(
            f"{k} {100 * r['reproduced']:.0f} %" for k, r in report["dynamics"].items()) + "): it was not recorded in "
            "one of ours; pass --dynamics brax, d4rl or v5 to evaluate in one anyway")
    return report["best"], {"how": "checked: replayed from infos/qpos, infos/qvel", **report}


def replay_report(f: DatasetFile, env: str, transitions: int = 2000, infos: dict | None = None) -> dict:
    """:func:`minsubdt_jax.envs.dynamics_report` of ``f``'s transitions, replayed from its ``infos/qpos`` and
    ``infos/qvel`` (the rows of its loaded episodes: a trailing unfinished one is dropped); ``infos`` if already
    read (:func:`read_infos`).

    Raises:
      DatasetError: the file records no physics states, or its infos are damaged."""
    infos = read_infos(f.path) if infos is None else infos
    if "qpos" not in infos or "qvel" not in infos:
        raise DatasetError(f"{f.path} records no physics states (infos/qpos, infos/qvel): its dynamics cannot be "
                           f"checked")
    n = f.data.num_transitions
    return dynamics_report(env, f.data, infos["qpos"][:n], infos["qvel"][:n], transitions=transitions)


def _attr(f: h5py.File, name: str) -> str | None:
    v = f.attrs.get(name)
    return None if v is None else (v.decode() if isinstance(v, bytes) else str(v))
