"""Our Minari export read by d3rlpy's loader (``d3rlpy.datasets.get_minari``), and a few d3rlpy BC steps on it.

    pip install d3rlpy 'minsubdt-jax[minari]'      # d3rlpy brings torch; not a dependency of ours
    python experiments/d3rlpy_check.py [--env hopper] [--dataset medium] [--transitions 20000]

d3rlpy 2.8's ``get_minari`` always calls ``recover_environment()`` (d3rlpy #460), so an env-less Minari dataset
fails there. Ours name a registered gymnasium env (``minsubdt/<Env>-<dynamics>-v0``, ``minsubdt_jax.envs.gym_env``),
which gymnasium finds once ``minsubdt_jax`` is imported. The check: d3rlpy's replay buffer has our episodes, their
lengths, returns and actions; its env is ours (same observation and action spaces); d3rlpy's BC trains on it.
Writes nothing outside a temporary ``MINARI_DATASETS_PATH``; prints one JSON line with what it compared.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile

import numpy as np


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--env", default="hopper")
    p.add_argument("--dataset", default="medium")
    p.add_argument("--transitions", type=int, default=20_000)
    a = p.parse_args(argv)
    os.environ["MINARI_DATASETS_PATH"] = tempfile.mkdtemp(prefix="minari-d3rlpy-")
    import d3rlpy

    import minsubdt_jax.envs.gym_env  # noqa: F401  (registers minsubdt/* with gymnasium)
    from minsubdt_jax.data import resolve_dataset
    from minsubdt_jax.data.d4rl import file_dynamics
    from minsubdt_jax.data.minari_io import export_minari

    f = resolve_dataset(a.env, a.dataset, transitions=a.transitions)
    dataset_id = f"minsubdt/{a.env}-{a.dataset}-v0"
    export_minari(f, a.env, dataset_id, file_dynamics(f, a.env)[0])
    buffer, env = d3rlpy.datasets.get_minari(dataset_id)
    d = f.data
    eps = buffer.episodes
    lengths = np.array([e.size() for e in eps])
    returns = np.array([float(np.sum(e.rewards)) for e in eps])
    acts = np.concatenate([e.actions for e in eps])
    ours_acts = d.actions[d.valid_mask()]
    out = {"d3rlpy": d3rlpy.__version__, "dataset_id": dataset_id, "sha256": f.sha256, "episodes": len(eps),
           "episodes_ours": d.num_trajectories, "lengths_equal": bool(np.array_equal(lengths, d.lengths)),
           "returns_max_abs_diff": float(np.abs(returns - d.returns).max()),
           "actions_max_abs_diff": float(np.abs(acts - ours_acts).max()),
           "terminated_equal": bool(np.array_equal([bool(e.terminated) for e in eps], d.terminals)),
           "env": env.spec.id, "observation_space": str(env.observation_space), "action_space": str(env.action_space)}
    bc = d3rlpy.algos.BCConfig(batch_size=64).create(device="cpu:0")
    res = bc.fit(buffer, n_steps=200, n_steps_per_epoch=200, show_progress=False, save_interval=10**9,
                 experiment_name="d3rlpy-check", logger_adapter=d3rlpy.logging.NoopAdapterFactory())
    out["bc_loss_after_200_steps"] = float(res[-1][1]["loss"])
    obs, _ = env.reset(seed=0)
    out["bc_action_shape"] = list(bc.predict(obs[None]).shape)
    ok = (out["episodes"] == out["episodes_ours"] and out["lengths_equal"] and out["returns_max_abs_diff"] < 1e-3
          and out["actions_max_abs_diff"] == 0.0 and out["terminated_equal"])
    out["ok"] = bool(ok)
    print(json.dumps(out))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
