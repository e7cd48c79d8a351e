"""Record every named dataset and tabulate it, and plot the behaviour policies' training curves.

    python experiments/datasets.py                       # 3 envs x 5 datasets at D4RL's sizes, C MuJoCo on a CPU
    python experiments/datasets.py --envs hopper --transitions 100000 --physics mjx
    python experiments/datasets.py --datasets medium-replay   # re-record only these; other rows are kept
    python experiments/datasets.py --datasets medium-replay --cached   # tabulate the cached files, no timing

Writes ``experiments/results/datasets.{json,md}`` and ``experiments/results/behavior_curves.png``. Datasets are
recorded into the user cache (``python -m minsubdt_jax.data`` uses the same files); existing files are
recorded again so that every time is a real generation time. ``medium-expert`` is assembled from the
medium and expert files, so its time is only the assembly.
"""

from __future__ import annotations

import argparse
import json
import os
import time

from minsubdt_jax.behavior.snapshots import load_manifest
from minsubdt_jax.data.named import NAMED_DATASETS, d4rl_transitions, dataset_path, resolve_dataset, summary
from minsubdt_jax.envs import PHYSICS, resolve_physics
from minsubdt_jax.atomic import atomic_open, save_figure

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")


def plot_curves(envs, png):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.5), dpi=100)
    for env in envs:
        m = load_manifest(env)
        c = m["training"]["curve"]
        for ax, x in zip(axes, ("step", "wall_seconds")):
            ax.plot([r[x] / (1 if x == "step" else 60) for r in c], [r["return_mean"] for r in c], label=env)
    axes[0].set(xlabel="env steps", ylabel="eval return (8 stochastic episodes)")
    axes[1].set(xlabel="wall minutes (2 trainers sharing 2 cores)")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend()
    fig.suptitle("SAC behaviour policies in MJX")
    fig.tight_layout()
    save_figure(fig, png)
    plt.close(fig)


def seconds(row) -> str:
    return "–" if row["seconds"] is None else f"{row['seconds']:.0f}"


def file_cell(row) -> str:
    if "file" not in row:
        return "not recorded (a recording made before files were named in this table)"
    return f"{row['file']} ({row['sha256'][:12]})"


def kept_rows(a) -> list[dict]:
    """The rows of the existing ``datasets.json`` that this call does not record again (same size and seed)."""
    path = os.path.join(RESULTS, "datasets.json")
    if not os.path.exists(path):
        return []
    with open(path) as f:
        old = json.load(f)
    if (old["transitions"], old["seed"], old.get("physics", "mjx")) != (a.transitions or "d4rl", a.seed, a.physics):
        return []
    return [r for r in old["rows"] if not (r["env"] in a.envs and r["dataset"] in a.datasets)]


def main(argv=None):
    from minsubdt_jax.envs import ENVS

    p = argparse.ArgumentParser()
    p.add_argument("--envs", nargs="+", default=["hopper", "walker", "halfcheetah"], choices=tuple(ENVS))
    p.add_argument("--transitions", type=int, default=None, help="default: D4RL's size of each dataset")
    p.add_argument("--physics", choices=PHYSICS, default="auto")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--datasets", nargs="+", default=list(NAMED_DATASETS), choices=NAMED_DATASETS)
    p.add_argument("--cached", action="store_true", help="use files already in the cache (no generation time)")
    a = p.parse_args(argv)
    a.physics = resolve_physics(a.physics)
    os.makedirs(RESULTS, exist_ok=True)
    rows = kept_rows(a)
    for env in a.envs:
        for ds in a.datasets:
            n = a.transitions or d4rl_transitions(env, ds)
            path = dataset_path(env, ds, n, 1000, a.seed, a.physics)
            if os.path.exists(path) and not a.cached:
                os.remove(path)
            t0 = time.time()
            f = resolve_dataset(env, ds, transitions=n, seed=a.seed, verbose=False, physics=a.physics)
            rows.append({"env": env, "dataset": ds, **summary(env, f.data), "seconds": None if a.cached else time.time() - t0,
                         "file": os.path.basename(f.path), "sha256": f.sha256, "physics": a.physics})
            r = rows[-1]
            print(f"{env:12s} {ds:14s} {r['episodes']:6d} {r['transitions']:8d} {r['return_mean']:8.1f} ± "
                  f"{r['return_std']:7.1f} {r['normalized_score_mean']:6.1f} {r['seconds'] or 0:6.1f} s", flush=True)
    order = {(e, d): i for i, (e, d) in enumerate((e, d) for e in ("hopper", "walker", "halfcheetah")
                                                   for d in NAMED_DATASETS)}
    rows.sort(key=lambda r: order[r["env"], r["dataset"]])
    with atomic_open(os.path.join(RESULTS, "datasets.json")) as f:
        json.dump({"transitions": a.transitions or "d4rl", "seed": a.seed, "physics": a.physics, "rows": rows}, f,
                  indent=1)
    lines = ["| env | dataset | episodes | transitions | return (mean ± std) | normalised score | generation (s) | "
             "file (sha256) |", "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['env']} | {r['dataset']} | {r['episodes']} | {r['transitions']} | {r['return_mean']:.1f} ± "
              f"{r['return_std']:.1f} | {r['normalized_score_mean']:.1f} | "
              f"{seconds(r)} | "
              f"{file_cell(r)} |" for r in rows]
    with atomic_open(os.path.join(RESULTS, "datasets.md")) as f:
        f.write("\n".join(lines) + "\n")
    plot_curves(a.envs, os.path.join(RESULTS, "behavior_curves.png"))


if __name__ == "__main__":
    main()
