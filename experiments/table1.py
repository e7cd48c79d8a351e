"""The seed's Table 1 on our MJX datasets: MinSubDT (engineered / learned costs), DT (true returns) and BC.

    python experiments/table1.py                      # run what is missing (cpu preset, 3 seeds), then aggregate
    python experiments/table1.py run --seeds 0 --envs hopper --datasets medium
    python experiments/table1.py run --preset paper --envs walker --datasets medium   # one unit: 4 methods x 3 seeds
    python experiments/table1.py aggregate            # tables and plots from the results present

Every run (env x dataset x method x seed) is one model; its compact result goes to
``experiments/results/table1/{preset}/{name}.json`` (with the dataset's content hash and the platform), and a run
whose result exists is skipped, so an interrupted sweep resumes where it stopped (the lowest missing seed of
every cell first). In each env x dataset the methods missing the same consecutive seeds a..b train as one
program, ``--method m1,m2,... --seeds S`` (a unit: up to 4 methods x 3 seeds = 12 models vmapped in one jitted
step), checkpointed (resumable, also across machines) in ``runs/table1/{preset}/{env}-{dataset}-{m1+m2...}-s{a}-{b}``. The datasets are the
named datasets of ``minsubdt_jax.data`` (recorded once, ``--dataset-seed 0``), fixed across training seeds.
``aggregate`` writes ``experiments/results/table1.md`` / ``.json`` (normalised score mean ± std over the
seeds present, with their count; averages with and without medium-replay; the better-than-demonstrated
report) and ``experiments/results/table1_costs_{env}.png`` (demos' vs rollouts' engineered cost features).
"""

from __future__ import annotations

import argparse
import dataclasses
import glob
import json
import os
import sys
import time
import traceback

import numpy as np

from minsubdt_jax.methods import METHODS as ALL_METHODS

ENVS = ("halfcheetah", "hopper", "walker")
DATASETS = ("medium-expert", "medium", "medium-replay")
METHODS = ("minsubdt", "minsubdt-learned", "dt", "bc")  # the seed's MinSubDT (engg., learned), DT and BC columns
METHOD_NAMES = {m: ALL_METHODS[m].label for m in METHODS}
RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")

# Seed Table 1 (gym/D4RL v2 datasets, normalised by D4RL's references): not comparable one to one with ours.
PUBLISHED = {
    (d, e): dict(zip(METHODS, v)) for (d, e), v in {
        ("medium-expert", "halfcheetah"): (89.5, 86.8, 87.0, 59.9),
        ("medium-expert", "hopper"): (110.7, 110.8, 107.6, 79.6),
        ("medium-expert", "walker"): (108.1, 108.5, 108.1, 36.6),
        ("medium", "halfcheetah"): (41.3, 40.9, 42.6, 43.1),
        ("medium", "hopper"): (56.8, 55.8, 67.6, 63.9),
        ("medium", "walker"): (70.4, 74.9, 74.0, 77.3),
        ("medium-replay", "halfcheetah"): (32.3, 31.8, 36.6, 4.3),
        ("medium-replay", "hopper"): (40.5, 37.1, 82.7, 27.6),
        ("medium-replay", "walker"): (37.1, 36.0, 66.6, 36.9),
    }.items()
}


def run_name(env, dataset, method, seed) -> str:
    return f"{env}-{dataset}-{method}-s{seed}"


def result_dir(preset: str, results_root: str = RESULTS) -> str:
    return os.path.join(results_root, "table1", preset)


def compact(results: dict) -> dict:
    """The part of ``train``'s results.json that the table needs, floats rounded (small files to commit)."""
    def rnd(x):
        if isinstance(x, float):
            return round(x, 5)
        if isinstance(x, list):
            return [rnd(v) for v in x]
        if isinstance(x, dict):
            return {k: rnd(v) for k, v in x.items()}
        return x

    return rnd({k: results[k] for k in ("config", "method", "dataset", "train", "eval", "references", "platform")
                if k in results})


def seed_runs(seeds) -> list[tuple[int, int]]:
    """Sorted seeds -> ``(first, count)`` runs of consecutive seeds, each one ``--seeds count`` program."""
    runs = []
    for s in sorted(set(seeds)):
        if runs and runs[-1][0] + runs[-1][1] == s:
            runs[-1] = (runs[-1][0], runs[-1][1] + 1)
        else:
            runs.append((s, 1))
    return runs


def per_seed_results(res: dict, i: int) -> dict:
    """Model ``i`` of a run's results (one of its methods x seeds), shaped as that model's single run would report
    them: its method and seed in the config, its own data summary and evaluation."""
    model = res["models"][i] if "models" in res else {"method": res["config"]["method"], "seed": res["config"]["seed"]}
    out = {k: v for k, v in res.items() if k not in ("seeds", "models", "methods", "eval_per_seed", "eval_by_method",
                                                        "dataset_per_model")}
    out["config"] = dict(res["config"], method=model["method"], seed=model["seed"], seeds=1)
    if "dataset_per_model" in res:
        out["dataset"] = dict(res["dataset_per_model"][i], costs_sample=res["dataset"].get("costs_sample", []))
    if "eval_per_seed" in res:
        out["eval"] = res["eval_per_seed"][i]
    return out


def run_sweep(preset="cpu", envs=ENVS, datasets=DATASETS, methods=METHODS, seeds=(0, 1, 2), runs_root="runs/table1",
              results_root=RESULTS, train_fn=None, log=print) -> dict:
    """Trains every missing run; returns ``{"done": [...], "skipped": [...], "failed": [...]}`` (run names).

    In each env x dataset, the methods missing the same seeds train together, and a run of consecutive missing
    seeds is one program: ``--method a,b,... --seeds S``, every (method, seed) a model vmapped in one jitted step
    (equal to single runs: ``tests/test_scale_out.py``). Each model's result is written as its own file; the
    lowest missing seed of every cell goes first."""
    if train_fn is None:
        from minsubdt_jax.train import train as train_fn
    from minsubdt_jax.config import PRESETS

    out_dir = result_dir(preset, results_root)
    os.makedirs(out_dir, exist_ok=True)
    path = lambda e, d, m, s: os.path.join(out_dir, run_name(e, d, m, s) + ".json")  # noqa: E731
    status = {"done": [], "skipped": [], "failed": []}
    todo = []
    for d in datasets:
        for e in envs:
            groups = {}  # (missing seeds, agent) -> the methods missing exactly them (in the order asked)
            for m in methods:
                have = [s for s in seeds if os.path.exists(path(e, d, m, s))]
                status["skipped"] += [run_name(e, d, m, s) for s in have]
                missing = tuple(sorted(set(seeds) - set(have)))
                if missing:
                    groups.setdefault((missing, ALL_METHODS[m].agent), []).append(m)
            for (missing, _), ms in groups.items():
                todo += [(first, d, e, tuple(ms), n) for first, n in seed_runs(missing)]
    todo.sort(key=lambda t: t[0])  # the lowest missing seed of every cell first (stable: datasets, envs, methods)
    for i, (first, ds, env, ms, n) in enumerate(todo):
        names = [run_name(env, ds, m, s) for m in ms for s in range(first, first + n)]
        label = "+".join(ms) + f" {env}-{ds} s{first}" + (f"-{first + n - 1}" if n > 1 else "")
        suffix = f"-s{first}" if n == 1 else f"-s{first}-{first + n - 1}"
        cfg = dataclasses.replace(PRESETS[preset], env=env, dataset=ds, method=",".join(ms), seed=first, seeds=n,
                                  out=os.path.join(runs_root, preset, f"{env}-{ds}-{'+'.join(ms)}{suffix}"))
        log(f"[{i + 1}/{len(todo)}] {label} ...")
        t0 = time.time()
        try:
            res = train_fn(cfg, resume=os.path.exists(os.path.join(cfg.out, "config.json")), verbose=False)
        except Exception:  # one failed program must not stop the sweep; it is reported and retried next time
            log(traceback.format_exc())
            status["failed"] += names
            continue
        scores = []
        for j, name in enumerate(names):
            one = per_seed_results(res, j)
            m, s = one["config"]["method"], one["config"]["seed"]
            dst = path(env, ds, m, s)
            assert name == run_name(env, ds, m, s), (name, m, s)
            with open(dst + ".tmp", "w") as f:
                json.dump(compact(one), f)
            os.replace(dst + ".tmp", dst)  # a result file is complete or absent
            scores.append(f"{one.get('eval', {}).get('normalized_score_mean', float('nan')):.1f}")
        log(f"[{i + 1}/{len(todo)}] {label}: normalised {' '.join(scores)} ({time.time() - t0:.0f} s)")
        status["done"] += names
    return status


def load_results(preset="cpu", results_root=RESULTS) -> list[dict]:
    rows = []
    for path in sorted(glob.glob(os.path.join(result_dir(preset, results_root), "*.json"))):
        with open(path) as f:
            r = json.load(f)
        c = r["config"]
        rows.append({"env": c["env"], "dataset": c["dataset"], "method": c["method"], "seed": c["seed"], "r": r})
    return rows


def aggregate(preset="cpu", results_root=RESULTS, out_root=RESULTS, plots=True) -> dict:
    """Writes table1.md / table1.json (and the cost plots) from the results present; returns the table."""
    rows = load_results(preset, results_root)
    cells = {}
    for row in rows:
        ev = row["r"].get("eval")
        if ev is None:
            continue
        c = cells.setdefault((row["dataset"], row["env"], row["method"]), {"scores": [], "seeds": [], "btd": [],
                                                                          "ms": [], "ms_demo": []})
        c["scores"].append(ev["normalized_score_mean"])
        c["seeds"].append(row["seed"])
        c["btd"].append(ev["better_than_mean_demo_share"])
        c["ms"].append(ev["min_subdominance_mean"])
        c["ms_demo"].append(row["r"]["dataset"]["min_subdominance_mean"] if row["method"] == "minsubdt" else None)
    table = {}
    for (ds, env, m), c in cells.items():
        s = np.asarray(c["scores"])
        table.setdefault(f"{ds}/{env}", {})[m] = {
            "mean": float(s.mean()), "std": float(s.std()), "n_seeds": len(s), "seeds": sorted(c["seeds"]),
            "better_than_mean_demo_share": float(np.mean(c["btd"])), "rollout_min_subdominance": float(np.mean(c["ms"])),
        }
    averages = {}
    for label, keep in (("all", DATASETS), ("without medium-replay", ("medium-expert", "medium"))):
        for m in METHODS:
            vals = [table[f"{d}/{e}"][m]["mean"] for d in keep for e in ENVS if m in table.get(f"{d}/{e}", {})]
            averages.setdefault(label, {})[m] = {"mean": float(np.mean(vals)) if vals else None, "cells": len(vals),
                                                 "of": len(keep) * len(ENVS)}
    costs = {}
    for row in rows:  # rank agreement of -min-subdominance with the true return, per cost representation
        key = f"{row['dataset']}/{row['env']}"
        ds = row["r"]["dataset"]
        if row["method"] == "minsubdt":
            costs.setdefault(key, {})["engineered_spearman"] = ds["spearman_neg_min_subdominance_vs_return"]
        elif row["method"] == "minsubdt-learned":
            lc = costs.setdefault(key, {}).setdefault("learned", [])
            lc.append({"seed": row["seed"], "spearman": ds["spearman_neg_min_subdominance_vs_return"],
                       "heldout_pair_accuracy": ds["learned_costs"]["heldout_pair_accuracy"]})
    demo = {f"{d}/{e}": next((r["r"]["dataset"]["normalized_score_mean"] for r in rows
                              if r["dataset"] == d and r["env"] == e), None) for d in DATASETS for e in ENVS}
    files = {}
    for row in rows:  # which recording of each dataset the runs used (the file name holds the recipe version)
        ds = row["r"]["dataset"]
        files.setdefault(f"{row['dataset']}/{row['env']}", set()).add(
            (os.path.basename(ds.get("path", "?")), ds.get("sha256", "not recorded")[:12], "+".join(ds["costs_mean"])))
    files = {k: [{"file": f, "sha256": h, "cost_features": c} for f, h, c in sorted(v)] for k, v in files.items()}
    episodes = sorted({r["r"]["eval"]["episodes"] for r in rows if "eval" in r["r"]})
    out = {"preset": preset, "eval_episodes": "/".join(map(str, episodes)) or "–", "runs": len(rows), "table": table, "averages": averages, "dataset_score": demo,
           "cost_rank_agreement": costs, "data_files": files,
           "published_seed_table1_gym_d4rl": {f"{d}/{e}": v for (d, e), v in PUBLISHED.items()}}
    os.makedirs(out_root, exist_ok=True)
    with open(os.path.join(out_root, "table1.json"), "w") as f:
        json.dump(out, f, indent=2)
    with open(os.path.join(out_root, "table1.md"), "w") as f:
        f.write(markdown(out))
    if plots and rows:
        for env in ENVS:
            plot_costs(rows, env, os.path.join(out_root, f"table1_costs_{env}.png"))
    return out


def _cell(entry) -> str:
    """``mean ± std (seeds)``; one seed has no spread to show, so it says so instead of "± 0.0"."""
    if entry is None:
        return "–"
    if entry["n_seeds"] == 1:
        return f"{entry['mean']:.1f} (1 seed)"
    return f"{entry['mean']:.1f} ± {entry['std']:.1f} ({entry['n_seeds']})"


def markdown(out: dict) -> str:
    cols = [METHOD_NAMES[m] for m in METHODS]
    lines = [f"# Table 1 on our MJX datasets (preset `{out['preset']}`)", "",
             "Normalised score (100 = committed SAC expert, 0 = uniform random, in MJX), mean ± std over the "
             f"training seeds present (their count in brackets), {out.get('eval_episodes', '?')} evaluation "
             f"episodes per seed at the `{out['preset']}` preset. '–' = not run yet. Regenerate: "
             f"`python experiments/table1.py --preset {out['preset']}` (runs what is missing, then aggregates).", "",
             *([] if out["preset"] == "paper" else [
                 f"**Not a result**: the `{out['preset']}` preset is a stage of training, not a converged score "
                 "(README, *What the presets are for*); the `paper` preset is. See *Data* below for the dataset "
                 "files and cost features these runs used.", ""]),
             "| dataset | env | dataset's own | " + " | ".join(cols) + " |", "|---|---|---|" + "---|" * len(cols)]

    def cells(fmt):  # one markdown row per dataset x env: "| d | e | " + fmt(d, e, table row) + " |"
        return [f"| {d} | {e} | {fmt(d, e, out['table'].get(f'{d}/{e}', {}))} |" for d in DATASETS for e in ENVS]

    def own(d, e):
        v = out["dataset_score"].get(f"{d}/{e}")
        return "–" if v is None else f"{v:.1f}"

    lines += cells(lambda d, e, row: own(d, e) + " | " + " | ".join(_cell(row.get(m)) for m in METHODS))
    for label, av in out["averages"].items():
        lines.append(f"| **average ({label})** | | | " + " | ".join(
            "–" if av[m]["mean"] is None else f"{av[m]['mean']:.1f} ({av[m]['cells']}/{av[m]['of']} cells)"
            for m in METHODS) + " |")
    lines += ["", "## Better than demonstrated?", "",
              "Share of evaluation rollouts that dominate the dataset's mean demo in the engineered cost features "
              "(none above it, one below), "
              "and the rollouts' min-subdominance (eq. 2, engineered features) against the demos (lower is "
              "better); mean over seeds.", "",
              "| dataset | env | " + " | ".join(cols) + " |", "|---|---|" + "---|" * len(cols)]
    lines += cells(lambda d, e, row: " | ".join(
        "–" if m not in row else f"{row[m]['better_than_mean_demo_share']:.0%} / {row[m]['rollout_min_subdominance']:.2f}"
        for m in METHODS))
    lines += ["", "## Cost representations: do they rank the demos like the true return?", "",
              "Spearman correlation of −min-subdominance (eq. 2, leave-one-out over the dataset) with the true "
              "return, for the engineered features and for the learned ones (eq. 3; K' = 2, mean over seeds), "
              "and the learned costs' held-out preference accuracy (pairs among the 20 % of trajectories "
              "held out of training). Per feature, over all episodes and over those that never fell, for the "
              "designs considered: [cost_features.md](cost_features.md).", "",
              "| dataset | env | engineered: Spearman | learned: Spearman | learned: held-out pair accuracy |",
              "|---|---|---|---|---|"]

    def agreement(d, e, _):
        c = out["cost_rank_agreement"].get(f"{d}/{e}", {})
        eng, lr = c.get("engineered_spearman"), c.get("learned", [])
        sp = f"{np.mean([x['spearman'] for x in lr]):.3f} ({len(lr)})" if lr else "–"
        acc = f"{np.mean([x['heldout_pair_accuracy'] for x in lr]):.3f}" if lr else "–"
        return f"{'–' if eng is None else f'{eng:.3f}'} | {sp} | {acc}"

    lines += cells(agreement)
    lines += ["", "## Data", "",
              "The dataset file(s) the runs of each cell used (the name holds the recording recipe; hash of the "
              "episodes, where the run recorded it) and their engineered cost features. A cell whose file is not "
              "today's `python -m minsubdt_jax.data` recording, or whose features are not today's "
              "`minsubdt_jax.costs`, was run on an earlier recipe.", "",
              "| dataset | env | file (sha256): cost features |", "|---|---|---|"]
    lines += [f"| {d} | {e} | " + "; ".join(f"{x['file']} ({x['sha256']}): {x['cost_features']}" for x in
                                             out.get("data_files", {}).get(f"{d}/{e}", [])) + " |"
              for d in DATASETS for e in ENVS]
    lines += ["", "## Published (seed Table 1: gym MuJoCo, D4RL v2 data, D4RL normalisation)", "",
              "Not comparable one to one with the table above: other physics, other behaviour policies, other "
              "references, 100k training steps. For orientation only.", "",
              "| dataset | env | " + " | ".join(cols) + " |", "|---|---|" + "---|" * len(cols)]
    for (d, e), v in PUBLISHED.items():
        lines.append(f"| {d} | {e} | " + " | ".join(f"{v[m]:.1f}" for m in METHODS) + " |")
    return "\n".join(lines) + "\n"


def plot_costs(rows, env, png):
    """Per dataset: the demos' engineered cost features (a sample) against every method's rollouts."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in rows if r["env"] == env and r["r"].get("eval")]
    if not rows:
        return
    fig, axes = plt.subplots(1, len(DATASETS), figsize=(4.2 * len(DATASETS), 3.6), dpi=100, squeeze=False)
    for ax, d in zip(axes[0], DATASETS):
        rs = [r for r in rows if r["dataset"] == d]
        if not rs:
            ax.set_title(f"{env} {d}: no runs yet")
            continue
        demo = np.asarray(rs[0]["r"]["dataset"]["costs_sample"])
        groups = [("demos", demo)] + [(METHOD_NAMES[m], np.concatenate([np.asarray(r["r"]["eval"]["costs"])
                                                                       for r in rs if r["method"] == m]))
                                      for m in METHODS if any(r["method"] == m for r in rs)]
        for gi, (label, pts) in enumerate(groups):
            if pts.shape[1] >= 2:
                ax.scatter(pts[:, 0], pts[:, 1], s=8 if gi == 0 else 18, alpha=0.35 if gi == 0 else 0.8, label=label)
            else:
                ax.scatter(pts[:, 0], gi + 0.15 * np.random.default_rng(gi).normal(size=len(pts)), s=10, label=label)
        names = list(rs[0]["r"]["dataset"]["costs_mean"])
        ax.set(title=f"{env} {d}", xlabel=f"{names[0]} cost")
        ax.set_ylabel(f"{names[1]} cost" if len(names) > 1 else "group")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(png)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("action", nargs="?", default="all", choices=["all", "run", "aggregate"])
    p.add_argument("--preset", default="cpu")
    p.add_argument("--envs", nargs="+", default=list(ENVS), choices=ENVS)
    p.add_argument("--datasets", nargs="+", default=list(DATASETS), choices=DATASETS)
    p.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    p.add_argument("--runs-root", default="runs/table1", help="training run directories (checkpoints)")
    a = p.parse_args(argv)
    from minsubdt_jax.config import PRESETS

    if a.preset not in PRESETS:
        p.error(f"--preset must be one of {list(PRESETS)}")
    failed = []
    if a.action in ("all", "run"):
        st = run_sweep(a.preset, a.envs, a.datasets, a.methods, a.seeds, a.runs_root)
        print(f"done {len(st['done'])}, already there {len(st['skipped'])}, failed {len(st['failed'])}", flush=True)
        failed = st["failed"]
    if a.action in ("all", "aggregate"):
        out = aggregate(a.preset)
        print(markdown(out))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
