"""``python -m minsubdt_jax.data --env walker --dataset medium``: record a named dataset into the cache.

    python -m minsubdt_jax.data --env hopper --dataset medium                        # D4RL's size, C MuJoCo on a CPU
    python -m minsubdt_jax.data --env hopper --dataset medium --physics mjx          # recorded in MJX instead
    python -m minsubdt_jax.data --env hopper --dataset hopper-medium-v2.hdf5 --check-dynamics   # which dynamics?
    python -m minsubdt_jax.data --env walker --dataset medium --costs x_velocity,energy   # the data on chosen metrics
    python -m minsubdt_jax.data --env walker --dataset medium --costs list                # the built-in metrics
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import sys
import time

import numpy as np

from ..caches import enable_compilation_cache
from ..costs import check_costs, cost_metrics, describe_metrics, spearman, trajectory_costs
from ..envs import ENVS, PHYSICS, resolve_physics
from ..rundir import exit_code
from ..subdominance import min_subdominance
from .d4rl import file_dynamics, replay_report
from ..envs.check import NEITHER
from .minari_io import check_minari_id, export_minari
from .dataset import DatasetError
from .named import NAMED_DATASETS, d4rl_transitions, dataset_path, resolve_dataset, summary_line


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m minsubdt_jax.data",
                                description="Record a D4RL-style dataset from the committed behaviour policies, or "
                                            "check which dynamics a dataset file came from.")
    p.add_argument("--env", required=True, choices=tuple(ENVS), help="the environment the data is recorded in (or, "
                   "for a file, checked against)")
    p.add_argument("--dataset", required=True, help=f"one of {', '.join(NAMED_DATASETS)}, or (with "
                                                    f"--check-dynamics) a D4RL-layout .hdf5 file")
    p.add_argument("--transitions", type=int, default=None,
                   help="at least this many transitions, in whole episodes (default D4RL's size: 1M; medium-replay "
                        "hopper 402k, walker 302k, halfcheetah 202k); medium-expert holds twice this")
    p.add_argument("--horizon", type=int, default=1000, help="the episodes' length limit: an episode that has not "
                   "fallen by then ends in a time-out (D4RL's 1000)")
    p.add_argument("--seed", type=int, default=0, help="the recording's seed (resets and the behaviour policy's "
                   "sampled actions); a recording is the same for the same seed and physics on one kind of CPU "
                   "(another instruction set may record another file: docs/FIDELITY.md)")
    p.add_argument("--physics", choices=PHYSICS, default="auto",
                   help="who steps the recording: C MuJoCo (mujoco), MJX (mjx), or auto (C MuJoCo on a CPU)")
    p.add_argument("--force", action="store_true", help="record again even if the cache holds the file")
    p.add_argument("--check-dynamics", action="store_true",
                   help="replay the file's transitions from its recorded physics states under each dynamics and "
                        "print how well each reproduces them")
    p.add_argument("--check-transitions", type=int, default=2000, help="transitions replayed by --check-dynamics")
    p.add_argument("--export-minari", metavar="ID", default=None,
                   help="write the dataset (named, or a file of ours) as the local Minari dataset ID (the [minari] "
                        "extra; under $MINARI_DATASETS_PATH); train on it with --dataset minari:ID")
    p.add_argument("--costs", default=None,
                   help="comma-separated cost metrics (minsubdt_jax.costs; 'list' lists them): print the dataset's "
                        "mean cost and min-subdominance on them")
    a = p.parse_args(argv)
    if a.costs == "list":
        print("\n".join(describe_metrics(a.env)))
        return 0
    if a.costs is not None and exit_code(lambda: check_costs(a.env, a.costs)):
        return 2  # before anything is recorded
    enable_compilation_cache()
    if a.check_dynamics:
        return exit_code(lambda: check(a.env, a.dataset, a.check_transitions, a.horizon, a.seed, a.physics))
    if a.export_minari:
        return exit_code(lambda: export(a.env, a.dataset, a.export_minari, a.transitions, a.horizon, a.seed,
                                        a.physics))
    if a.dataset not in NAMED_DATASETS:
        p.error(f"--dataset must be one of {list(NAMED_DATASETS)} to record (a file is for --check-dynamics)")
    return exit_code(lambda: record(a.env, a.dataset, a.transitions, a.horizon, a.seed, a.force, a.physics, a.costs))


def record(env: str, dataset: str, transitions: int | None, horizon: int, seed: int, force: bool,
           physics: str = "auto", costs: str | None = None) -> None:
    transitions = d4rl_transitions(env, dataset) if transitions is None else transitions
    if transitions < 1 or horizon < 1:
        raise DatasetError(f"transitions and horizon must be >= 1, got {transitions} and {horizon}")
    physics = resolve_physics(physics)
    path = dataset_path(env, dataset, transitions, horizon, seed, physics)
    if force and os.path.exists(path):
        os.remove(path)
    cached = os.path.exists(path)
    t0 = time.time()
    f = resolve_dataset(env, dataset, transitions=transitions, horizon=horizon, seed=seed, physics=physics)
    if cached:
        print(summary_line(env, dataset, f.data, time.time() - t0, horizon) + f" (cached: {f.path})")
    if costs is not None:
        print_costs(env, f.data, costs, horizon)


def print_costs(env: str, data, costs: str, horizon: int) -> dict:
    """The dataset's mean cost per metric of ``costs`` and its min-subdominance on them (eq. 2, leave-one-out)."""
    metrics = cost_metrics(env, costs)
    F = np.asarray(trajectory_costs(metrics, data.observations, data.lengths, max(horizon, data.max_len),
                                    terminated=data.terminals, actions=data.actions))
    ms = np.asarray(min_subdominance(F, F, 1.0, leave_one_out=True).value)
    out = {"costs_mean": {m.name: float(v) for m, v in zip(metrics, F.mean(0))},
           "min_subdominance_mean": float(ms.mean()), "spearman_neg_min_subdominance_vs_return": spearman(-ms, data.returns)}
    for m, v in zip(metrics, F.mean(0)):
        print(f"  {m.name}: mean cost {v:.3f} ({m.meaning})")
    print(f"  min-subdominance {ms.mean():.3f} ± {ms.std():.3f} (beta 1); Spearman(-min-subdominance, true return) "
          f"{out['spearman_neg_min_subdominance_vs_return']:.3f}")
    return out


def export(env: str, dataset: str, dataset_id: str, transitions: int | None, horizon: int, seed: int,
           physics: str) -> str:
    """Record or load ``dataset`` and write it as the local Minari dataset ``dataset_id``
    (:func:`~minsubdt_jax.data.minari_io.export_minari`), in the dynamics it was recorded in."""
    if importlib.util.find_spec("minari") is None:  # before anything is recorded
        raise DatasetError("--export-minari needs the minari package: pip install 'minsubdt-jax[minari]'")
    check_minari_id(dataset_id)
    f = resolve_dataset(env, dataset, transitions=transitions, horizon=horizon, seed=seed, physics=physics)
    dynamics, how = file_dynamics(f, env)
    folder = export_minari(f, env, dataset_id, dynamics)
    print(f"wrote the Minari dataset {dataset_id} ({f.data.num_trajectories} episodes, {dynamics} dynamics: "
          f"{how['how']}) to {folder}; train on it with --dataset minari:{dataset_id}")
    return folder


def check(env: str, dataset: str, transitions: int, horizon: int, seed: int, physics: str) -> dict:
    """Print and return the replay report (:func:`~minsubdt_jax.data.d4rl.replay_report`) of a file (or a cached
    named dataset)."""
    f = resolve_dataset(env, dataset, horizon=horizon, seed=seed, physics=physics)
    rep = replay_report(f, env, transitions)
    print(f"{f.path}: {rep['transitions']} transitions replayed from their recorded states (tolerance "
          f"{rep['tolerance']:g} on the largest |Δobs|)")
    for name, r in rep["dynamics"].items():
        print(f"  {name:5s} largest |Δobs| {r['max']:.3g}, median {r['median']:.3g}, reproduced "
              f"{100 * r['reproduced']:.1f} %")
    if "same_states" in rep:
        errs = {k: rep["dynamics"][k].get("terminal_reward_error") for k in rep["same_states"]}
        print(f"  {' and '.join(rep['same_states'])} step the same states; " + (
            "the terminal steps' rewards decide: largest |Δreward| " + ", ".join(f"{k} {v:.3g}" for k, v in errs.items())
            if None not in errs.values() else "no episode terminated, so nothing tells them apart"))
    said = f" (the file says {f.dynamics})" if f.dynamics else ""
    print(f"the data came from the {rep['best']} dynamics{said}" if rep["best"] != NEITHER else
          f"neither dynamics reproduces the data{said}: it was recorded in other physics, or edited")
    print(json.dumps({"path": f.path, **rep}))
    return rep


if __name__ == "__main__":
    sys.exit(main())
