"""Minari datasets (D4RL's successor format) out and in: the optional extra ``pip install 'minsubdt-jax[minari]'``.

    python -m minsubdt_jax.data --env walker --dataset medium --export-minari minsubdt/walker/medium-v0
    python -m minsubdt_jax.train --env walker --dataset minari:minsubdt/walker/medium-v0

Out (:func:`export_minari`): one Minari episode per episode of a D4RL-layout file, with the T+1 observations Minari
keeps: the final one is computed by one step of the last action from the recorded last physics state
(``infos/qpos, qvel``) under the file's dynamics (:func:`minsubdt_jax.envs.check.final_observations`).
``terminations`` mark a fall, ``truncations`` a time-out or the end of the data. Its metadata holds our reference
scores (``ref_min_score``, ``ref_max_score``: Minari's ``get_normalized_score`` gives the 0-1 fraction, ours the
0-100 score), the file's content hash, its env, dynamics and physics, and its recording recipe (the file name).
The dataset is written under ``MINARI_DATASETS_PATH`` (default ``~/.minari/datasets``) with the env spec of our
env as a gymnasium env (:mod:`minsubdt_jax.envs.gym_env`, e.g. ``minsubdt/Walker-brax-v0``), so
``dataset.recover_environment()`` (which d3rlpy's ``get_minari`` calls) makes it.

In (:func:`open_minari`): ``--dataset minari:ID`` loads a local Minari dataset of this env's shapes as a
:class:`~minsubdt_jax.data.d4rl.DatasetFile` (the final observations dropped; its hash is of the episodes as
loaded). A dataset we exported names its dynamics; any other needs ``--dynamics``.
"""

from __future__ import annotations

import os

import numpy as np

from ..envs.check import final_observations
from ..references import SCALE, reference_returns
from .d4rl import DatasetFile, read_infos
from .dataset import DatasetError, from_flat, from_padded

PREFIX = "minari:"


def _minari():
    try:
        import minari
    except ImportError:
        raise DatasetError("Minari datasets need the minari package: pip install 'minsubdt-jax[minari]'") from None
    return minari


def check_minari_id(dataset_id: str) -> None:
    """DatasetError unless ``dataset_id`` is a Minari id with a version (a malformed one left a folder that broke
    every later Minari load until removed by hand)."""
    from minari.dataset.minari_dataset import parse_dataset_id

    try:
        parse_dataset_id(dataset_id)
    except (ValueError, TypeError):  # TypeError: no -v<version>
        raise DatasetError(f"--export-minari {dataset_id!r} is not a Minari dataset id: (namespace/)name-v<version>, "
                           f"of letters, digits, '-' and '_' (e.g. minsubdt/hopper/medium-v0)") from None


def export_minari(f: DatasetFile, env: str, dataset_id: str, dynamics: str) -> str:
    """Write ``f`` (episodes of ``env`` in ``dynamics``) as the local Minari dataset ``dataset_id``; returns its
    folder. Raises DatasetError if the file records no physics states or the id is taken."""
    minari = _minari()
    import gymnasium as gym
    from minari.data_collector.episode_buffer import EpisodeBuffer

    check_minari_id(dataset_id)
    if dataset_id in minari.list_local_datasets():
        raise DatasetError(f"a local Minari dataset {dataset_id!r} exists already (minari delete {dataset_id})")
    infos = read_infos(f.path)
    if "qpos" not in infos or "qvel" not in infos:
        raise DatasetError(f"{f.path} records no physics states (infos/qpos, infos/qvel), so the episodes' final "
                           f"observations, which Minari keeps, cannot be computed")
    d = f.data
    n = d.num_transitions
    final = final_observations(env, dynamics, d, infos["qpos"][:n], infos["qvel"][:n]).astype(np.float32)
    buffers = []
    for i in range(d.num_trajectories):
        L = int(d.lengths[i])
        end = np.zeros(L, bool)
        end[-1] = True
        buffers.append(EpisodeBuffer(
            id=i, observations=np.concatenate([d.observations[i, :L], final[i:i + 1]]).astype(np.float32),
            actions=d.actions[i, :L].astype(np.float32), rewards=d.rewards[i, :L].astype(np.float64).tolist(),
            terminations=(end & bool(d.terminals[i])).tolist(), truncations=(end & (not d.terminals[i])).tolist()))
    box = lambda dim, lim: gym.spaces.Box(-lim, lim, (dim,), np.float32)  # noqa: E731
    lo, hi = reference_returns(env, dynamics)
    ds = _create(minari, dataset_id, buffers, d, box, f, env, dynamics)
    ds.storage.update_metadata({"ref_min_score": float(lo), "ref_max_score": float(hi), "minsubdt_sha256": f.sha256,
                                "minsubdt_env": env, "minsubdt_dynamics": dynamics,
                                "minsubdt_physics": f.physics or "unknown", "minsubdt_recipe": os.path.basename(f.path),
                                "minsubdt_normalisation": SCALE})
    return os.path.dirname(os.path.normpath(str(ds.storage.data_path)))


def _create(minari, dataset_id, buffers, d, box, f, env, dynamics):
    import gymnasium as gym

    from ..envs.gym_env import IDS

    return minari.create_dataset_from_buffers(
        dataset_id, buffers, env=gym.spec(IDS[(env, dynamics)]), observation_space=box(d.obs_dim, np.inf),
        action_space=box(d.act_dim, 1.0),
        algorithm_name=f"minsubdt-jax recording {os.path.basename(f.path)}", author={"minsubdt-jax"},
        description=f"{env} episodes exported by minsubdt-jax from {os.path.basename(f.path)} (sha256 {f.sha256}), "
                    f"{dynamics} dynamics", data_format="hdf5")


def open_minari(name: str) -> DatasetFile:
    """``minari:ID`` -> the local Minari dataset ``ID`` as a :class:`DatasetFile`. Raises DatasetError when it is
    not there, or its episodes are not flat float vectors."""
    minari = _minari()
    dataset_id = name[len(PREFIX):]
    if dataset_id not in minari.list_local_datasets():
        raise DatasetError(f"no local Minari dataset {dataset_id!r} (under $MINARI_DATASETS_PATH or ~/.minari/datasets; "
                           f"these are: {sorted(minari.list_local_datasets()) or 'none'})")
    ds = minari.load_dataset(dataset_id)
    eps = list(ds.iterate_episodes())
    if not eps or any(np.ndim(e.observations) != 2 or np.ndim(e.actions) != 2 for e in eps):
        raise DatasetError(f"{name}: needs episodes of flat observation and action vectors")
    lengths = np.array([len(e.actions) for e in eps])
    T = int(lengths.max())
    pad = lambda x, L: np.concatenate([x, np.zeros((T - L,) + x.shape[1:], x.dtype)])  # noqa: E731
    data = from_padded(np.stack([pad(np.asarray(e.observations[:-1], np.float32), L) for e, L in zip(eps, lengths)]),
                       np.stack([pad(np.asarray(e.actions, np.float32), L) for e, L in zip(eps, lengths)]),
                       np.stack([pad(np.asarray(e.rewards, np.float32), L) for e, L in zip(eps, lengths)]),
                       lengths, np.array([bool(e.terminations[-1]) for e in eps]))
    data = from_flat(data.to_flat(), source=name)  # the checks every file gets: finite float32, flags, shapes
    meta = ds.storage.metadata
    env, dynamics = _env_and_dynamics(name, meta, ds.spec.env_spec)
    refs = None
    if meta.get("ref_min_score") is not None and meta.get("ref_max_score") is not None:
        refs = (float(meta["ref_min_score"]), float(meta["ref_max_score"]),
                f"the dataset's own (Minari metadata ref_min_score / ref_max_score of {dataset_id})")
    return DatasetFile(data=data, path=name, sha256=data.sha256(), env=env, dynamics=dynamics,
                       physics=meta.get("minsubdt_physics"), references=refs)


# gymnasium's MuJoCo envs whose rules we have (minsubdt_jax.envs.rules): id -> (env, dynamics)
GYM_ENVS = {f"{gym}-{v}": (env, dyn) for gym, env in (("Hopper", "hopper"), ("Walker2d", "walker"),
                                                       ("HalfCheetah", "halfcheetah"))
            for v, dyn in (("v4", "d4rl"), ("v5", "v5"))}


def _env_and_dynamics(name: str, meta: dict, env_spec) -> tuple[str | None, str | None]:
    """``(env, dynamics)`` of a Minari dataset: what our export's metadata says, else its env spec's gymnasium id
    (``Hopper-v5`` -> hopper in v5) when it names an env in rules we have with its default settings; an env spec
    we cannot serve is one DatasetError; no env spec: ``(None, None)`` (``--dynamics`` decides)."""
    if meta.get("minsubdt_dynamics"):
        return meta.get("minsubdt_env"), meta["minsubdt_dynamics"]
    if env_spec is None:
        return None, None
    served = GYM_ENVS.get(env_spec.id)
    odd = {k: v for k, v in (env_spec.kwargs or {}).items() if k not in ("render_mode",)}
    if served is None or odd:
        why = f"its env {env_spec.id}" + (f" with {odd}" if odd else "")
        raise DatasetError(f"{name}: {why} is not one we can evaluate in; we have "
                           f"{', '.join(sorted(GYM_ENVS))} at their defaults (and our own exports)")
    return served
