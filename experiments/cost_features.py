"""Do the engineered cost features rank the demonstrations like the true return? Per feature, per dataset.

    python experiments/cost_features.py                       # 3 envs x medium, medium-replay, medium-expert
    python experiments/cost_features.py --envs hopper --datasets medium

For each dataset (recorded into the cache on first use) and each candidate design of the features, it computes
min-subdominance (eq. 2, leave-one-out, beta = 1) and reports the Spearman correlation with the true return of

* each feature's part of -min-subdominance (``MinSubdominance.per_feature``), over all episodes and over the
  episodes that never fell (time-outs only: survival says nothing there);
* the total, next to x-velocity alone.

Designs (z only for hopper and walker):

* ``x``: x-velocity alone;
* ``x+z``: x- and signed z-velocity, alpha free (the seed's pair, as first built: mean z-velocity of a periodic
  gait is ~0, so this feature mostly measures the horizon not lived);
* ``x+z-speed``: the z feature is vertical *slowness*, ``1 - min(|v_z|, hi) / hi`` per step: cost falls with
  vertical speed, as the x cost falls with forward speed ("how slow did the robot move", in each direction);
* ``x+z-bounce``: the opposite reading, ``min(|v_z|, hi) / hi``: cost rises with vertical motion;
* ``x+fell``: the second feature keeps only what all the z designs share, the steps not lived: ``(H - L) / H``
  for a trajectory that fell, 0 otherwise (per-step cost 0 while upright);
* each of the three with ``alpha <= beta/std``: each feature's alpha capped at ``beta / std_k`` (std over the
  demos): to dominate a demo by the margin, a trajectory must beat it by a standard deviation of that feature.

Writes ``experiments/results/cost_features.{md,json}``.
"""

from __future__ import annotations

import argparse
import json
import os

import numpy as np

from minsubdt_jax.costs import engineered_costs, horizon_average, spearman
from minsubdt_jax.data import resolve_dataset
from minsubdt_jax.envs import env_spec
from minsubdt_jax.subdominance import min_subdominance
from minsubdt_jax.atomic import atomic_open

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
Z_HI = 2.0  # m/s: the clip range [-2, 2] of the z-velocity cost as first built
Z_DESIGNS = ("z", "z-speed", "z-bounce", "fell")
DESIGNS = ("x",) + tuple(f"x+{z}{cap}" for z in Z_DESIGNS for cap in ("", ", alpha <= beta/std"))


def z_cost(env: str, data, horizon: int, kind: str):
    """``[N]`` the second feature of one design, falls charged the worst cost 1 for the steps not lived."""
    vz = data.observations[..., env_spec(env).z_velocity_index]
    speed = np.clip(np.abs(vz) / Z_HI, 0, 1)
    per_step = {"z": (Z_HI - np.clip(vz, -Z_HI, Z_HI)) / (2 * Z_HI), "z-speed": 1 - speed, "z-bounce": speed,
                "fell": 0 * speed}[kind]
    return np.asarray(horizon_average(per_step[..., None], data.lengths, horizon, data.terminals))[:, 0]


def design_features(env: str, design: str, data, horizon: int):
    """``(features [N, K], alpha_max [K] or None)`` of one design."""
    x = np.asarray(engineered_costs(env, data.observations, data.lengths, horizon, terminated=data.terminals))[:, :1]
    z = design.split(",")[0].removeprefix("x").removeprefix("+")
    F = x if not z else np.concatenate([x, z_cost(env, data, horizon, z)[:, None]], 1)
    cap = 1.0 / np.maximum(F.std(0), 1e-12) if "alpha <=" in design else None
    return F, cap


def analyse(env: str, dataset: str, transitions: int | None, horizon: int = 1000, physics: str = "auto") -> dict:
    f = resolve_dataset(env, dataset, transitions=transitions, horizon=horizon, verbose=True, physics=physics)
    data = f.data
    R = data.returns
    alive = ~data.terminals
    out = {"env": env, "dataset": dataset, "file": os.path.basename(f.path), "sha256": f.sha256,
           "episodes": data.num_trajectories, "never_fell": int(alive.sum()),
           "designs": {}}
    for design in DESIGNS:
        if env == "halfcheetah" and design != "x":
            continue
        F, cap = design_features(env, design, data, horizon)
        ms = min_subdominance(F, F, 1.0, alpha_max=cap, leave_one_out=True)
        part = -np.asarray(ms.per_feature)
        row = {"total": spearman(-np.asarray(ms.value), R),
               "total_never_fell": spearman(-np.asarray(ms.value)[alive], R[alive]) if alive.sum() > 2 else None,
               "per_feature": [spearman(part[:, k], R) for k in range(F.shape[1])],
               "per_feature_never_fell": [spearman(part[alive, k], R[alive]) if alive.sum() > 2 else None
                                          for k in range(F.shape[1])]}
        out["designs"][design] = row
    return out


def markdown(rows: list[dict]) -> str:
    fmt = lambda v: "–" if v is None or (isinstance(v, float) and np.isnan(v)) else f"{v:+.2f}"  # noqa: E731
    lines = ["# Engineered cost features: rank agreement with the true return", "",
             "Spearman correlation with the true return of −min-subdominance (eq. 2, leave-one-out, β = 1) and of "
             "each feature's part of it, over all episodes / over the episodes that never fell. Regenerate: "
             "`python experiments/cost_features.py` (designs in its docstring). '–': no episode of that kind, or a "
             "constant part (no information). The library's engineered costs are `x+fell` "
             "(`minsubdt_jax.costs`): the only design whose total never ranks worse than x alone, over all episodes "
             "or over those that never fell.", "",
             "| env | dataset | episodes (never fell) | design | total | x part | second feature's part |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        for design, d in r["designs"].items():
            pf, pa = d["per_feature"], d["per_feature_never_fell"]
            z = f"{fmt(pf[1])} / {fmt(pa[1])}" if len(pf) > 1 else "–"
            lines.append(f"| {r['env']} | {r['dataset']} | {r['episodes']} ({r['never_fell']}) | {design} | "
                         f"{fmt(d['total'])} / {fmt(d['total_never_fell'])} | {fmt(pf[0])} / {fmt(pa[0])} | {z} |")
    lines += ["", "Dataset files (recorded by `python -m minsubdt_jax.data` on this machine; sha256 of the episodes):", ""]
    lines += [f"- {r['env']} {r['dataset']}: `{r['file']}` ({r['sha256'][:16]})" for r in rows]
    return "\n".join(lines) + "\n"


def main(argv=None):
    from minsubdt_jax.data import NAMED_DATASETS
    from minsubdt_jax.envs import ENVS

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--envs", nargs="+", default=["hopper", "walker", "halfcheetah"], choices=tuple(ENVS))
    p.add_argument("--datasets", nargs="+", default=["medium", "medium-replay", "medium-expert"],
                   choices=NAMED_DATASETS)
    p.add_argument("--transitions", type=int, default=None, help="default: D4RL's size of each dataset")
    p.add_argument("--physics", default="auto", choices=["auto", "mjx", "mujoco"])
    p.add_argument("--out", default=RESULTS)
    a = p.parse_args(argv)
    rows = [analyse(e, d, a.transitions, physics=a.physics) for e in a.envs for d in a.datasets]
    os.makedirs(a.out, exist_ok=True)
    with atomic_open(os.path.join(a.out, "cost_features.json")) as f:
        json.dump(rows, f, indent=1)
    with atomic_open(os.path.join(a.out, "cost_features.md")) as f:
        f.write(markdown(rows))
    print(markdown(rows))


if __name__ == "__main__":
    main()
