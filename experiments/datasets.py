"""Record every named dataset and tabulate it, and plot the behaviour policies' training curves.

    python experiments/datasets.py                       # 3 envs x 5 datasets, 100k transitions each
    python experiments/datasets.py --envs hopper --transitions 1000000

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
from minsubdt_jax.data.named import DEFAULT_TRANSITIONS, NAMED_DATASETS, dataset_path, resolve_dataset, summary

HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")


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
    fig.savefig(png)
    plt.close(fig)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--envs", nargs="+", default=["hopper", "walker", "halfcheetah"])
    p.add_argument("--transitions", type=int, default=DEFAULT_TRANSITIONS)
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args()
    os.makedirs(HERE, exist_ok=True)
    rows = []
    for env in a.envs:
        for ds in NAMED_DATASETS:
            path = dataset_path(env, ds, a.transitions, 1000, a.seed)
            if os.path.exists(path):
                os.remove(path)
            t0 = time.time()
            data = resolve_dataset(env, ds, transitions=a.transitions, seed=a.seed, verbose=False).data
            rows.append({"env": env, "dataset": ds, **summary(env, data), "seconds": time.time() - t0})
            r = rows[-1]
            print(f"{env:12s} {ds:14s} {r['episodes']:6d} {r['transitions']:8d} {r['return_mean']:8.1f} ± "
                  f"{r['return_std']:7.1f} {r['normalized_score_mean']:6.1f} {r['seconds']:6.1f} s", flush=True)
    with open(os.path.join(HERE, "datasets.json"), "w") as f:
        json.dump({"transitions": a.transitions, "seed": a.seed, "rows": rows}, f, indent=1)
    lines = ["| env | dataset | episodes | transitions | return (mean ± std) | normalised score | generation (s) |",
             "|---|---|---|---|---|---|---|"]
    lines += [f"| {r['env']} | {r['dataset']} | {r['episodes']} | {r['transitions']} | {r['return_mean']:.1f} ± "
              f"{r['return_std']:.1f} | {r['normalized_score_mean']:.1f} | {r['seconds']:.0f} |" for r in rows]
    with open(os.path.join(HERE, "datasets.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    plot_curves(a.envs, os.path.join(HERE, "behavior_curves.png"))


if __name__ == "__main__":
    main()
