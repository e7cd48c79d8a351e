"""The committed behaviour policies: snapshot files, their manifests (which snapshot is expert, medium, replay;
the MJX normalisation references), and rollouts of a snapshot's stochastic actor.

Nothing here trains: recording a dataset or reading a normalisation reference needs only this module
(:mod:`minsubdt_jax.behavior.train` writes snapshots, :mod:`minsubdt_jax.behavior.policies` exports them).
"""

from __future__ import annotations

import functools
import json
import os
from typing import Any

import jax
import numpy as np
from flax import traverse_util

from ..atomic import atomic_path
from ..envs import env_spec, make_rollout, random_policy
from .networks import policy_step

POLICY_DIR = os.path.join(os.path.dirname(__file__), "snapshots")


def save_snapshot(path: str, actor_params, **meta) -> None:
    """Actor parameters as a flat ``.npz`` (``params/torso/Dense_0/kernel`` …) plus scalar metadata."""
    flat = traverse_util.flatten_dict(jax.device_get(actor_params), sep="/")
    with atomic_path(path, suffix=".tmp.npz") as tmp:  # np.savez adds .npz to a name without it
        np.savez(tmp, **{k: np.asarray(v, np.float32) for k, v in flat.items()},
                 **{f"meta/{k}": np.asarray(v) for k, v in meta.items()})


def load_snapshot(path: str) -> tuple[Any, dict]:
    """``(actor_params, meta)`` saved by :func:`save_snapshot`."""
    with np.load(path) as z:
        params = traverse_util.unflatten_dict({k: z[k] for k in z.files if not k.startswith("meta/")}, sep="/")
        meta = {k[5:]: z[k].item() for k in z.files if k.startswith("meta/")}
    return params, meta


@functools.lru_cache(maxsize=None)
def load_manifest(env: str) -> dict:
    """The committed ``manifest.json`` for ``env`` (references, expert/medium/replay snapshot names)."""
    path = os.path.join(POLICY_DIR, env_spec(env).name, "manifest.json")
    if not os.path.exists(path):
        raise ValueError(f"no behaviour policies for {env!r} in {POLICY_DIR}: train them with "
                         f"`python -m minsubdt_jax.behavior.train --env {env}` and export them with "
                         f"`python -m minsubdt_jax.behavior.policies --env {env} --run runs/behavior/{env}`")
    with open(path) as f:
        return json.load(f)


def load_policy(env: str, role: str):
    """Actor parameters of the committed ``role`` (``expert`` or ``medium``) policy for ``env``."""
    return load_snapshot(os.path.join(POLICY_DIR, env_spec(env).name, load_manifest(env)[role]["snapshot"]))[0]


def load_replay_policies(env: str) -> list:
    """Actor parameters of medium-replay's snapshots, earliest first (the last is medium)."""
    d = os.path.join(POLICY_DIR, env_spec(env).name)
    return [load_snapshot(os.path.join(d, r["snapshot"]))[0] for r in load_manifest(env)["replay"]]


def replay_weights(env: str) -> list[float]:
    """The env steps that the random warm-up and each replay snapshot (:func:`load_replay_policies`) stand for in
    SAC's replay buffer up to the medium checkpoint, D4RL's medium-replay: ``[random, snapshot_1, ...]``.

    The warm-up took the first ``min_replay`` steps; after it, each step is given to the snapshot nearest in
    training time (boundaries at the midpoints between snapshots), up to the medium step, the last snapshot. The
    weights add up to the medium step."""
    m = load_manifest(env)
    warmup = float(m["training"]["config"]["min_replay"])
    steps = [float(r["step"]) for r in m["replay"]]
    edges = [warmup] + [(a + b) / 2 for a, b in zip(steps, steps[1:])] + [steps[-1]]
    return [warmup] + [max(hi - lo, 0.0) for lo, hi in zip(edges, edges[1:])]


def make_policy_rollout(env: str, actor_params, episodes: int, horizon: int, physics: str = "auto",
                        step=policy_step):
    """``(run, params)``: the rollout (``physics``, brax dynamics) of the actor ``actor_params`` acting by ``step``
    (the stochastic actor; ``None`` params: uniform random actions) over ``episodes`` parallel episodes, and the
    parameters to call it with."""
    if actor_params is None:
        return (make_rollout(env, random_policy, episodes, horizon, physics=physics),
                np.zeros(env_spec(env).act_dim, np.float32))
    return make_rollout(env, step, episodes, horizon, physics=physics), actor_params


def measure_return(env: str, actor_params, episodes: int, horizon: int = 1000, seed: int = 0,
                   physics: str = "auto") -> dict:
    """Mean ± std return of ``episodes`` stochastic episodes (``actor_params=None``: uniform random actions)."""
    run, params = make_policy_rollout(env, actor_params, episodes, horizon, physics)
    ro = jax.device_get(run(params, (), jax.random.PRNGKey(seed)))
    r = np.asarray(ro.rewards).sum(1)
    return {"return_mean": float(r.mean()), "return_std": float(r.std()), "episodes": int(episodes),
            "length_mean": float(np.mean(ro.lengths))}
