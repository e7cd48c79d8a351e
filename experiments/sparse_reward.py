"""What a discounted critic makes of MinSubDT's surrogate reward: one reward, -min-subdominance, at an episode's
last step (docs/critics.md).

    python experiments/sparse_reward.py [--discount 0.99] [--cells walker/medium hopper/medium-replay ...]

For each dataset (the D4RL-size recordings of ``minsubdt_jax.data``), over its transitions as the critic agents
sample them: how far each step is from its episode's end, how much of the surrogate reward a discounted backup
carries back to it (``gamma^(steps to the end)``), and, for comparison, the true reward's discounted value-to-go.
Writes ``experiments/results/sparse_reward.{md,json}``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np
from minsubdt_jax.atomic import atomic_open

HERE = os.path.dirname(os.path.abspath(__file__))
CELLS = ("walker/medium", "hopper/medium-replay", "halfcheetah/medium-expert")


def measure(env: str, dataset: str, discount: float) -> dict:
    from minsubdt_jax.costs import spearman
    from minsubdt_jax.config import Config
    from minsubdt_jax.methods import get_method
    from minsubdt_jax.pipeline import prepare

    cfg = Config(env=env, dataset=dataset)
    prep = prepare(cfg, get_method("minsubdt-iql"), verbose=False)
    d = prep.source.data
    L = d.lengths.astype(np.int64)
    t = np.arange(d.max_len)[None, :]
    valid = t < L[:, None]
    to_end = (L[:, None] - 1 - t)  # steps from t to the episode's last step
    carried = discount ** np.where(valid, to_end, 0)
    horizon = int(np.ceil(np.log(10) / (1 - discount)))  # gamma^h = 0.1
    surrogate = -prep.min_subdominance  # [N] the episode's one reward
    value_surrogate = carried * surrogate[:, None]  # [N, T] its discounted value-to-go at every step
    # the true reward's discounted value-to-go, by a backward pass
    r = np.where(valid, d.rewards, 0.0).astype(np.float64)
    v_true = np.zeros_like(r)
    acc = np.zeros(len(L))
    for k in range(d.max_len - 1, -1, -1):
        acc = r[:, k] + discount * acc * valid[:, k]
        v_true[:, k] = acc
    first = lambda v: v[:, 0]  # noqa: E731
    return {"env": env, "dataset": dataset, "file": os.path.basename(prep.source.path), "sha256": prep.source.sha256,
            "episodes": int(len(L)), "transitions": int(L.sum()), "terminated_share": float(d.terminals.mean()),
            "length_mean": float(L.mean()), "discount": discount, "horizon_10pct": horizon,
            "share_within_horizon": float((to_end[valid] < horizon).mean()),
            "carried_mean": float(carried[valid].mean()), "carried_at_start_median": float(np.median(first(carried))),
            "spearman_value_at_start_vs_surrogate_return": spearman(first(value_surrogate), surrogate),
            "spearman_true_value_at_start_vs_return": spearman(first(v_true), d.returns),
            "surrogate_value_at_start_abs_mean": float(np.abs(first(value_surrogate)).mean()),
            "surrogate_return_abs_mean": float(np.abs(surrogate).mean()),
            "tied_share": float(np.isclose(prep.min_subdominance, prep.features.shape[1] * cfg.beta).mean())}


def report(rows: list[dict]) -> str:
    g = rows[0]["discount"]
    lines = ["# The surrogate reward under a discounted critic", "",
             f"Made by `python experiments/sparse_reward.py` (discount {g}). MinSubDT's reward is one number per "
             "episode, `-min-subdominance`, paid at its last step. A backup with discount gamma carries "
             "`gamma^(steps to the end)` of it to an earlier step; the critics see no time in their state, so for "
             "a time-out they cannot tell how far the end is.", "",
             "| dataset | file (sha256) | episodes | terminated | mean length | transitions within "
             f"{rows[0]['horizon_10pct']} steps of the end (gamma^k >= 0.1) | mean gamma^(steps to end) | median "
             "at the first step | |value at the first step| / |surrogate return| | Spearman(value at start, "
             "surrogate return) | same for the true reward's value | demos tied at -K beta |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['env']} {r['dataset']} | {r['file']} ({r['sha256'][:12]}) | {r['episodes']} | "
                     f"{100 * r['terminated_share']:.0f} % | {r['length_mean']:.0f} | "
                     f"{100 * r['share_within_horizon']:.0f} % | {r['carried_mean']:.3f} | "
                     f"{r['carried_at_start_median']:.1e} | "
                     f"{r['surrogate_value_at_start_abs_mean'] / r['surrogate_return_abs_mean']:.1e} | "
                     f"{r['spearman_value_at_start_vs_surrogate_return']:.2f} | "
                     f"{r['spearman_true_value_at_start_vs_return']:.2f} | {100 * r['tied_share']:.0f} % |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--discount", type=float, default=0.99)
    p.add_argument("--cells", nargs="+", default=list(CELLS))
    a = p.parse_args(argv)
    rows = [measure(*c.split("/"), a.discount) for c in a.cells]
    out = os.path.join(HERE, "results")
    with atomic_open(os.path.join(out, "sparse_reward.json")) as f:
        json.dump(rows, f, indent=1)
    text = report(rows)
    with atomic_open(os.path.join(out, "sparse_reward.md")) as f:
        f.write(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
