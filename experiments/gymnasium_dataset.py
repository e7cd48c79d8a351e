"""A D4RL-layout file recorded by gymnasium's own ``Hopper-v4`` / ``Walker2d-v4`` / ``HalfCheetah-v4`` (or their
``-v5``, Minari's): data made outside this package, as a user's own D4RL file or Minari dataset would be.

    python experiments/gymnasium_dataset.py --env hopper --policy medium --episodes 100 --out hopper-v4-medium.hdf5
    python -m minsubdt_jax.data --env hopper --dataset hopper-v4-medium.hdf5 --check-dynamics   # -> d4rl
    python -m minsubdt_jax.train --env hopper --dataset hopper-v4-medium.hdf5   # evaluated in d4rl dynamics
    python experiments/gymnasium_dataset.py --env hopper --version v5 --transitions 1000000 \
        --out hopper-v5-medium.hdf5 --minari minsubdt/hopper-v5/medium-v0   # and as a Minari dataset of Hopper-v5

With ``--minari ID`` the same episodes are also written as a local Minari dataset whose env spec is gymnasium's
(``Hopper-v5``) and whose metadata has references measured as Minari measures them: the mean return of
``--ref-episodes`` episodes of uniform random actions and of the committed expert policy in the same env.

The actions come from a committed behaviour policy (``--policy medium|expert``, sampled from the stochastic actor;
it was trained in brax dynamics, so in gym's hopper it scores differently) or are uniform (``random``). The file
has D4RL's keys (``observations, actions, rewards, terminals, timeouts, next_observations, infos/qpos,
infos/qvel``; the physics state each action was taken in) and none of the attributes this package writes, so it
loads as a foreign file.
"""

from __future__ import annotations

import argparse
import os

import h5py
import jax
import numpy as np

GYM_IDS = {"hopper": "Hopper-{}", "walker": "Walker2d-{}", "halfcheetah": "HalfCheetah-{}"}


def record_rows(env: str, episodes: int | None, policy: str = "random", horizon: int = 1000, seed: int = 0,
                version: str = "v4", transitions: int | None = None) -> dict:
    """Whole episodes of ``policy`` in gymnasium's ``version`` env: ``episodes`` of them, or as many as hold at
    least ``transitions``; their flat per-step rows (D4RL's keys, ``qpos``, ``qvel``, ``episode_ends``)."""
    import gymnasium

    from minsubdt_jax.behavior.networks import policy_step
    from minsubdt_jax.behavior.snapshots import load_policy
    from minsubdt_jax.envs import env_spec

    spec = env_spec(env)
    g = gymnasium.make(GYM_IDS[spec.name].format(version), max_episode_steps=horizon)
    params = None if policy == "random" else load_policy(spec.name, policy)
    act = jax.jit(lambda p, o, k: policy_step(p, (), o[None], None, 0, k)[1][0])
    rng = np.random.default_rng(seed)
    key = jax.random.PRNGKey(seed)
    rows = {k: [] for k in ("observations", "actions", "rewards", "terminals", "timeouts", "next_observations",
                            "qpos", "qvel")}
    e = 0
    while (e < episodes) if episodes else (len(rows["rewards"]) < transitions):
        obs, _ = g.reset(seed=seed * 100_003 + e)
        done = False
        while not done:
            if params is None:
                a = rng.uniform(-1, 1, spec.act_dim).astype(np.float32)
            else:
                key, k = jax.random.split(key)
                a = np.clip(np.asarray(act(params, obs.astype(np.float32), k)), -1, 1)
            rows["qpos"].append(g.unwrapped.data.qpos.copy())
            rows["qvel"].append(g.unwrapped.data.qvel.copy())
            nxt, r, term, trunc, _ = g.step(a)
            for k, v in (("observations", obs), ("actions", a), ("rewards", r), ("terminals", term),
                         ("timeouts", trunc and not term), ("next_observations", nxt)):
                rows[k].append(v)
            obs, done = nxt, term or trunc
        e += 1
    return rows


def rows_of_file(path: str) -> dict:
    """The flat rows of a file :func:`record` wrote (a recording made once, exported to Minari again)."""
    with h5py.File(path, "r") as f:
        return {k: f[k][()] for k in ("observations", "actions", "rewards", "terminals", "timeouts",
                                      "next_observations")}


def returns_of(rows: dict) -> np.ndarray:
    ends = np.asarray(rows["terminals"]) | np.asarray(rows["timeouts"])
    return np.add.reduceat(np.asarray(rows["rewards"]), np.flatnonzero(np.r_[True, ends[:-1]]))


def record(env: str, episodes: int | None, out: str, policy: str = "random", horizon: int = 1000, seed: int = 0,
           version: str = "v4", transitions: int | None = None) -> dict:
    """Record episodes of ``policy`` in gymnasium's ``version`` env (:func:`record_rows`) and write them to ``out``."""
    rows = record_rows(env, episodes, policy, horizon, seed, version, transitions)
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    with h5py.File(out, "w") as f:
        for k, v in rows.items():
            dtype = bool if k in ("terminals", "timeouts") else np.float32
            f.create_dataset(k if k not in ("qpos", "qvel") else f"infos/{k}", data=np.asarray(v, dtype))
    returns = returns_of(rows)
    return {"episodes": len(returns), "transitions": len(rows["rewards"]), "return_mean": float(returns.mean()),
            "rows": rows}


def to_minari(rows: dict, env: str, version: str, dataset_id: str, horizon: int, ref_episodes: int, seed: int) -> dict:
    """The episodes of ``rows`` as a local Minari dataset of gymnasium's env, with references measured in it (the
    mean return of ``ref_episodes`` random and expert episodes, as Minari's ``create_dataset`` measures them)."""
    import gymnasium
    import minari
    from minari.data_collector.episode_buffer import EpisodeBuffer

    from minsubdt_jax.envs import env_spec

    col = {k: np.asarray(v) for k, v in rows.items()}  # once: a list of 1M rows is slow to convert
    ends = np.flatnonzero(col["terminals"] | col["timeouts"])
    starts = np.r_[0, ends[:-1] + 1]
    buffers = [EpisodeBuffer(id=i, observations=np.concatenate([col["observations"][s:t + 1],
                                                                 col["next_observations"][t:t + 1]]),
                             actions=col["actions"][s:t + 1], rewards=col["rewards"][s:t + 1].tolist(),
                             terminations=col["terminals"][s:t + 1].tolist(),
                             truncations=col["timeouts"][s:t + 1].tolist())
               for i, (s, t) in enumerate(zip(starts, ends))]
    gym_id = GYM_IDS[env_spec(env).name].format(version)
    refs = {p: float(returns_of(record_rows(env, ref_episodes, p, horizon, seed + 1, version)).mean())
            for p in ("random", "expert")}
    g = gymnasium.make(gym_id, max_episode_steps=horizon)
    minari.create_dataset_from_buffers(
        dataset_id, buffers, env=g.spec, observation_space=g.observation_space, action_space=g.action_space,
        algorithm_name="minsubdt-jax committed SAC behaviour policy", ref_min_score=refs["random"],
        ref_max_score=refs["expert"], author={"minsubdt-jax"}, description=f"{gym_id} episodes of our behaviour policy")
    return refs


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--env", default="hopper", choices=sorted(GYM_IDS))
    p.add_argument("--version", default="v4", choices=["v4", "v5"], help="gymnasium's env version")
    p.add_argument("--policy", default="medium", choices=["random", "medium", "expert"])
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--transitions", type=int, default=None, help="episodes until at least this many (over --episodes)")
    p.add_argument("--minari", default=None, help="also write a local Minari dataset of this id")
    p.add_argument("--ref-episodes", type=int, default=100, help="episodes per reference (with --minari)")
    p.add_argument("--horizon", type=int, default=1000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True)
    a = p.parse_args()
    if a.minari and os.path.exists(a.out):  # recorded already: export it
        rows = rows_of_file(a.out)
        out = {"episodes": len(returns_of(rows)), "transitions": len(rows["rewards"]), "from": a.out}
    else:
        out = record(a.env, None if a.transitions else a.episodes, a.out, a.policy, a.horizon, a.seed, a.version,
                     a.transitions)
        rows = out.pop("rows")
    if a.minari:
        out["references"] = to_minari(rows, a.env, a.version, a.minari, a.horizon, a.ref_episodes, a.seed)
    print(out, "->", a.out)


if __name__ == "__main__":
    main()
