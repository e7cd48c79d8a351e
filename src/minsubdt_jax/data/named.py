"""D4RL-style datasets recorded from the committed behaviour policies (brax dynamics, C MuJoCo or MJX), cached.

    python -m minsubdt_jax.data --env walker --dataset medium                     # D4RL's size: 1M transitions
    python -m minsubdt_jax.data --env hopper --dataset medium-replay --transitions 100000   # a smaller one

* ``random``: uniformly random actions;
* ``medium`` / ``expert``: the committed medium / expert SAC snapshot, actions sampled from the stochastic
  policy (as D4RL did);
* ``medium-replay``: D4RL's replay buffer up to the medium checkpoint, rebuilt from the committed snapshots of
  that training: the random policy (SAC's warm-up) and each snapshot record shares of the transitions in
  proportion to the env steps they stand for (:func:`~minsubdt_jax.behavior.snapshots.replay_weights`);
* ``medium-expert``: ``medium`` ∪ ``expert`` (each of ``transitions``, so twice the size, as in D4RL);
* ``mo-expert`` / ``mo-amateur`` (issue 74, D4MORL's two kinds): the committed trade-off policies
  (:mod:`minsubdt_jax.behavior.tradeoffs`) in equal shares, the stochastic actor, or PEDA's amateur (its action
  scaled by U(0.35, 1.65) with probability 0.65); each transition labelled with its policy's preference
  ``infos/preference`` ``[speed, energy]``.

Episodes are whole (``horizon`` steps unless terminated) and collected in batches until at least
``transitions`` transitions (by default D4RL's size, :func:`d4rl_transitions`); everything is a function of the
seed and the physics (C MuJoCo and MJX give the same episodes up to float rounding, which chaos amplifies). Files go to
``$XDG_CACHE_HOME/minsubdt_jax/datasets`` (else ``~/.cache/...``) in the D4RL layout plus ``infos/qpos``,
``infos/qvel``, ``infos/x_velocity``, ``infos/z_velocity`` (of the state each action was taken in).
"""

from __future__ import annotations

import contextlib
import fcntl
import math
import os
import time

import jax
import numpy as np

from ..behavior import tradeoffs
from ..behavior.networks import amateur_policy_step, policy_step
from ..behavior.snapshots import load_policy, load_replay_policies, make_policy_rollout, replay_weights
from ..caches import cache_dir
from ..envs import check_dataset, env_spec, resolve_physics
from ..scoring import score_episodes
from .d4rl import DatasetFile, open_d4rl, read_infos, save_d4rl
from .dataset import DatasetError, Trajectories, concatenate, from_padded, pad_concat
from .minari_io import PREFIX, open_minari

NAMED_DATASETS = ("random", "medium", "medium-replay", "expert", "medium-expert", "mo-expert", "mo-amateur")
# a recipe that changed gets a new file name, so no cache file recorded the old way stands in for the new one
RECIPE_VERSION = {"medium-replay": 2}
# D4RL's sizes (its -v2 files): medium, expert and random 1M; medium-replay the replay buffer up to the medium
# policy; medium-expert is medium + expert, each of this size
D4RL_TRANSITIONS = {"random": 1_000_000, "medium": 1_000_000, "expert": 1_000_000, "medium-expert": 1_000_000,
                    "medium-replay": None,  # the env's own (EnvSpec.replay_transitions)
                    "mo-expert": 1_000_000, "mo-amateur": 1_000_000}
MAX_BATCH = 128  # episodes per rollout call (at most)


def d4rl_transitions(env: str, dataset: str) -> int:
    """D4RL's size of ``dataset`` for ``env`` (the default of ``--transitions``; medium-expert: per part)."""
    n = D4RL_TRANSITIONS[dataset]
    return env_spec(env).replay_transitions if n is None else n


def dataset_path(env: str, dataset: str, transitions: int, horizon: int, seed: int, physics: str = "mujoco") -> str:
    version = f"-v{RECIPE_VERSION[dataset]}" if dataset in RECIPE_VERSION else ""
    backend = "" if physics == "mjx" else f"-{physics}"  # MJX recordings keep the names they always had
    return os.path.join(cache_dir(), "datasets",
                        f"{env_spec(env).name}-{dataset}{version}-t{transitions}-h{horizon}-s{seed}{backend}.hdf5")


def collect(env: str, actor_params, transitions: int, horizon: int, rng, bar=None, physics: str = "auto",
            step=policy_step) -> tuple[Trajectories, dict]:
    """Whole episodes of one policy (``actor_params=None``: uniform random actions), batched, until they hold at
    least ``transitions`` transitions. Returns the episodes and their flat per-step ``infos``."""
    # enough episodes in one call when they average a quarter of the horizon; one compiled shape per call site
    batch = max(1, min(MAX_BATCH, 4 * math.ceil(transitions / horizon)))
    run, actor_params = make_policy_rollout(env, actor_params, batch, horizon, physics, step)
    parts, total, i = [], 0, 0
    while total < transitions:
        ro = jax.device_get(run(actor_params, (), jax.random.fold_in(rng, i)))
        lengths = np.asarray(ro.lengths)
        keep = int(np.searchsorted(np.cumsum(lengths), transitions - total)) + 1  # episodes needed, at most batch
        ro = jax.tree.map(lambda x: np.asarray(x)[:keep], ro)
        parts.append(ro)
        added = int(ro.lengths.sum())
        total += added
        i += 1
        if bar is not None:
            bar.update(added)
    ro = jax.tree.map(lambda *xs: pad_concat(xs), *parts)
    data = from_padded(ro.observations, ro.actions, ro.rewards, ro.lengths, ro.terminated)
    mask = data.valid_mask()
    qpos, qvel = ro.qpos[:, :data.max_len][mask], ro.qvel[:, :data.max_len][mask]
    infos = {"qpos": qpos, "qvel": qvel, "x_velocity": qvel[:, 0], "z_velocity": qvel[:, 1]}
    return data, infos


def generate(env: str, dataset: str, transitions: int | None = None, horizon: int = 1000, seed: int = 0,
             verbose: bool = True, physics: str = "auto") -> tuple[Trajectories, dict]:
    """Record the named ``dataset`` (not ``medium-expert``, which :func:`resolve_dataset` assembles)."""
    from tqdm import tqdm

    step, labels = policy_step, None
    if dataset == "random":
        policies, weights = [None], [1.0]
    elif dataset in ("medium", "expert"):
        policies, weights = [load_policy(env, dataset)], [1.0]
    elif dataset == "medium-replay":
        policies, weights = [None, *load_replay_policies(env)], replay_weights(env)
    elif dataset in ("mo-expert", "mo-amateur"):
        family = tradeoffs.load_policies(env)
        policies, labels, weights = [p for p, _ in family], [r["preference"] for _, r in family], [1.0] * len(family)
        step = amateur_policy_step if dataset == "mo-amateur" else policy_step
    else:
        raise DatasetError(f"cannot record {dataset!r} directly; choose one of {list(NAMED_DATASETS)}")
    transitions = d4rl_transitions(env, dataset) if transitions is None else transitions
    shares = [math.ceil(transitions * w / sum(weights)) for w in weights]
    rng = jax.random.PRNGKey(seed)
    with tqdm(total=sum(shares), disable=not verbose, unit="transition", unit_scale=True,
              desc=f"{env_spec(env).name}/{dataset}", dynamic_ncols=True, mininterval=1.0) as bar:
        parts = [collect(env, p, n, horizon, jax.random.fold_in(rng, j), bar, physics, step)
                 for j, (p, n) in enumerate(zip(policies, shares))]
    for j, (data, infos) in enumerate(parts if labels else []):  # each transition's policy's preference
        infos["preference"] = np.tile(np.asarray(labels[j], np.float32), (data.num_transitions, 1))
    return concatenate([d for d, _ in parts]), {k: np.concatenate([i[k] for _, i in parts]) for k in parts[0][1]}


def generate_random(env: str, episodes: int, horizon: int, seed: int, physics: str = "auto") -> Trajectories:
    """Exactly ``episodes`` episodes of uniformly random actions (for tests and small experiments)."""
    run, params = make_policy_rollout(env, None, episodes, horizon, physics)
    ro = jax.device_get(run(params, (), jax.random.PRNGKey(seed)))
    return from_padded(ro.observations, ro.actions, ro.rewards, ro.lengths, ro.terminated)


def resolve_dataset(env: str, dataset: str, *, transitions: int | None = None, horizon: int = 1000,
                    seed: int = 0, verbose: bool = True, physics: str = "auto") -> DatasetFile:
    """Load ``dataset`` for ``env``: a path to a D4RL-layout hdf5 file, or a name in ``NAMED_DATASETS`` (recorded
    into the cache on first use in ``physics``, brax dynamics, ``transitions`` or D4RL's size), checked against the
    env (:func:`minsubdt_jax.envs.check_dataset`).

    A recording holds a lock on its cache file, so concurrent processes asking for the same dataset record it
    once: the others wait, then load the finished file. Readers never see a partial file (see ``save_d4rl``).

    Raises:
      DatasetError: a bad file or name, a damaged cache file (the message says how to record it again), or data
        that cannot come from ``env``.
    """
    if dataset.startswith(PREFIX):  # a local Minari dataset
        return _checked(open_minari(dataset), env)
    if os.sep in dataset or dataset.endswith((".hdf5", ".h5")) or os.path.exists(dataset):
        return _checked(open_d4rl(dataset, horizon), env)
    if dataset not in NAMED_DATASETS:
        raise DatasetError(f"unknown dataset {dataset!r}: give a path to a D4RL-layout .hdf5 file or one of "
                           f"{list(NAMED_DATASETS)}")
    transitions = d4rl_transitions(env, dataset) if transitions is None else transitions
    if transitions < 1 or horizon < 1:
        raise DatasetError(f"transitions and horizon must be >= 1, got {transitions} and {horizon}")
    try:
        physics = resolve_physics(physics)
    except ValueError as e:
        raise DatasetError(str(e)) from None
    path = dataset_path(env, dataset, transitions, horizon, seed, physics)
    if os.path.exists(path):  # complete (it appears only by a rename): read it without the lock, so a read-only
        _remove_orphans(path)  # cache works
        return _checked(_open_cached(path, env, dataset), env)
    with _lock(path, dataset):
        if os.path.exists(path):
            return _checked(_open_cached(path, env, dataset), env)
        _remove_orphans(path, locked=True)
        t0 = time.time()
        if dataset == "medium-expert":
            parts = [resolve_dataset(env, d, transitions=transitions, horizon=horizon, seed=seed, verbose=verbose,
                                     physics=physics) for d in ("medium", "expert")]
            data = concatenate([p.data for p in parts])
            infos = {k: np.concatenate([read_infos(p.path)[k] for p in parts]) for k in read_infos(parts[0].path)}
        else:
            data, infos = generate(env, dataset, transitions, horizon, seed, verbose, physics)
        digest = save_d4rl(data, path, infos, env=env_spec(env).name, dynamics="brax", physics=physics)
    if verbose:
        print(summary_line(env, dataset, data, time.time() - t0, horizon) + f" -> {path}", flush=True)
    return _checked(DatasetFile(data, path, digest, env_spec(env).name, dynamics="brax", physics=physics), env)


def _checked(f: DatasetFile, env: str) -> DatasetFile:
    try:
        check_dataset(env, f.data.observations, f.data.actions, f.data.lengths, f.env)
    except ValueError as e:
        raise DatasetError(f"{f.path}: {e}") from None
    return f


def _open_cached(path: str, env: str, dataset: str) -> DatasetFile:
    try:
        return open_d4rl(path)
    except DatasetError as e:
        raise DatasetError(f"{e}. It is a cached recording: record it again with `python -m minsubdt_jax.data --env "
                           f"{env_spec(env).name} --dataset {dataset} --force` (with the same --transitions, "
                           f"--horizon, --seed and --physics), or delete the file") from None


@contextlib.contextmanager
def _lock(path: str, dataset: str = "the dataset"):
    """An exclusive lock on ``path + '.lock'`` (blocks while another process holds it); a cache folder that cannot
    be written is one DatasetError."""
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        f = open(path + ".lock", "a")
    except OSError as e:
        raise DatasetError(f"cannot record {dataset} into the cache {os.path.dirname(path)} ({e.strerror or e}): "
                           f"set XDG_CACHE_HOME to a writable folder") from None
    with f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def _remove_orphans(path: str, locked: bool = False) -> None:
    """Remove the temporary files that killed recordings of ``path`` left (``save_d4rl`` writes ``<name>.*.tmp``
    and renames it). Only while no process records it: under its lock (``locked``), or when the lock can be taken
    at once; a cache that cannot be written is left as it is."""
    folder, name = os.path.split(path)
    try:
        orphans = [os.path.join(folder, f) for f in os.listdir(folder) if f.startswith(name + ".") and
                   f.endswith(".tmp")]
        if not orphans:
            return
        if locked:
            for o in orphans:
                os.remove(o)
            return
        with open(path + ".lock", "a") as f:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)  # raises while a recording holds it
            for o in orphans:
                os.remove(o)
            fcntl.flock(f, fcntl.LOCK_UN)
    except OSError:
        pass


def summary(env: str, data: Trajectories, horizon: int = 1000) -> dict:
    """Episodes, transitions, return, normalised score and engineered cost means of a dataset, scored as any
    policy's episodes are (:func:`minsubdt_jax.scoring.score_episodes`)."""
    s = score_episodes(env, data.observations, data.lengths, data.rewards, terminated=data.terminals,
                       horizon=max(horizon, data.max_len)).summary()
    keep = ("return_mean", "return_std", "normalized_score_mean", "normalized_score_std", "length_mean", "costs_mean")
    return {"episodes": data.num_trajectories, "transitions": data.num_transitions, **{k: s[k] for k in keep}}


def summary_line(env: str, dataset: str, data: Trajectories, seconds: float | None = None, horizon: int = 1000) -> str:
    s = summary(env, data, horizon)
    line = (f"{env_spec(env).name}/{dataset}: {s['episodes']} episodes, {s['transitions']} transitions, return "
            f"{s['return_mean']:.1f} ± {s['return_std']:.1f}, normalised score {s['normalized_score_mean']:.1f}")
    return line + (f" ({seconds:.0f} s)" if seconds is not None else "")
