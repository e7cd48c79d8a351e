"""A D4RL-layout file recorded by gymnasium's own ``Hopper-v4`` / ``Walker2d-v4`` / ``HalfCheetah-v4``: data made
outside this package, in D4RL's dynamics, as a user's own D4RL file would be.

    python experiments/gymnasium_dataset.py --env hopper --policy medium --episodes 100 --out hopper-v4-medium.hdf5
    python -m minsubdt_jax.data --env hopper --dataset hopper-v4-medium.hdf5 --check-dynamics   # -> d4rl
    python -m minsubdt_jax.train --env hopper --dataset hopper-v4-medium.hdf5   # evaluated in d4rl dynamics

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

GYM_IDS = {"hopper": "Hopper-v4", "walker": "Walker2d-v4", "halfcheetah": "HalfCheetah-v4"}


def record(env: str, episodes: int, out: str, policy: str = "random", horizon: int = 1000, seed: int = 0) -> dict:
    """Record ``episodes`` whole episodes of ``policy`` in gymnasium's v4 env and write them to ``out``."""
    import gymnasium

    from minsubdt_jax.behavior.networks import policy_step
    from minsubdt_jax.behavior.snapshots import load_policy
    from minsubdt_jax.envs import env_spec

    spec = env_spec(env)
    g = gymnasium.make(GYM_IDS[spec.name], max_episode_steps=horizon)
    params = None if policy == "random" else load_policy(spec.name, policy)
    act = jax.jit(lambda p, o, k: policy_step(p, (), o[None], None, 0, k)[1][0])
    rng = np.random.default_rng(seed)
    key = jax.random.PRNGKey(seed)
    rows = {k: [] for k in ("observations", "actions", "rewards", "terminals", "timeouts", "next_observations",
                            "qpos", "qvel")}
    for e in range(episodes):
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
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    with h5py.File(out, "w") as f:
        for k, v in rows.items():
            dtype = bool if k in ("terminals", "timeouts") else np.float32
            f.create_dataset(k if k not in ("qpos", "qvel") else f"infos/{k}", data=np.asarray(v, dtype))
    returns = np.add.reduceat(np.asarray(rows["rewards"]), np.flatnonzero(np.r_[True, (
        np.asarray(rows["terminals"]) | np.asarray(rows["timeouts"]))[:-1]]))
    return {"episodes": episodes, "transitions": len(rows["rewards"]), "return_mean": float(returns.mean())}


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--env", default="hopper", choices=sorted(GYM_IDS))
    p.add_argument("--policy", default="medium", choices=["random", "medium", "expert"])
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--horizon", type=int, default=1000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True)
    a = p.parse_args()
    print(record(a.env, a.episodes, a.out, a.policy, a.horizon, a.seed), "->", a.out)


if __name__ == "__main__":
    main()
