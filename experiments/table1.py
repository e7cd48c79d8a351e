"""The seed's Table 1 on our recorded datasets: MinSubDT (engineered / learned costs), DT (true returns) and BC.

    python experiments/table1.py                      # run what is missing (cpu preset, 3 seeds), then aggregate
    python experiments/table1.py run --seeds 0 --envs hopper --datasets medium
    python experiments/table1.py run --preset paper --envs walker --datasets medium   # one unit: 4 methods x 3 seeds
    python experiments/table1.py run --preset paper --envs walker     # one unit: 3 datasets x 4 methods x 3 seeds
    python experiments/table1.py run --preset study --commit   # a long sweep: each finished unit's files committed
    python experiments/table1.py aggregate            # tables and plots from the results present

Every run (env x dataset x method x seed) is one model; its compact result goes to
``experiments/results/table1/{preset}/{name}.json`` (with the dataset's content hash and the platform), and a run
whose result exists is skipped, so an interrupted sweep resumes where it stopped (the lowest missing seed of
every cell first); one trained with another config than the sweep's now (a changed preset) is an error. In each
env x dataset the methods missing the same consecutive seeds a..b train as one program, ``--method m1,m2,...
--seeds S`` (a unit: up to 4 methods x 3 seeds = 12 models vmapped in one jitted step; with ``--whole-env``, the
default at ``--preset paper``, an env's datasets too: 36 models, ``--dataset a,b,c``), checkpointed (resumable
after a cut at any chunk, also across machines) in ``runs/table1/{preset}/{env}-{dataset[+...]}-{m1+m2...}-s{a}-{b}``.
The datasets are the named datasets of ``minsubdt_jax.data`` (recorded once, ``--dataset-seed 0``), fixed across
training seeds.
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

# its siblings, beside it: a script's folder is on its path (the tests': pyproject's pythonpath)
from table1_report import (COLUMNS, DATASETS, ENVS, METHODS, PUBLISHED, PUBLISHED_BASELINES,
                           data_files, markdown, versus_dt)
import table1_compare
import table1_seeds
from table1_figures import model_curve, plot_cell_curves, plot_costs
from gitcommit import commit_results
from table1_units import (check_critic_settings, check_not_stale, compact, model_results, plan_units,
                          run_name)

from minsubdt_jax.atomic import atomic_open

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")


def result_dir(preset: str, results_root: str = RESULTS) -> str:
    return os.path.join(results_root, "table1", preset)


def variant(preset: str, costs: str | None = None) -> str:
    """The results' folder name: the preset, and the cost metrics when ``--costs`` chose them."""
    return preset if costs is None else f"{preset}-costs-{costs.replace(',', '+')}"


def run_sweep(preset="cpu", envs=ENVS, datasets=DATASETS, methods=METHODS, seeds=(0, 1, 2), runs_root="runs/table1",
              results_root=RESULTS, train_fn=None, log=print, physics="auto", costs=None, whole_env=False,
              on_unit=None, **overrides) -> dict:
    """Trains every missing run; returns ``{"done": [...], "skipped": [...], "failed": [...]}`` (run names).
    ``costs`` (``--costs``) chooses the cost metrics; its results go to their own folder (:func:`variant`).
    ``whole_env``: an env's datasets train in one program (:func:`table1_units.plan_units`); ``on_unit(paths,
    summary)`` is called with each finished unit's result files (``--commit`` commits them); ``overrides``:
    config fields set on the preset (``precision``: every agent's matmuls, issue 58).

    In each env x dataset, the methods missing the same seeds train together, and a run of consecutive missing
    seeds is one program: ``--method a,b,... --seeds S``, every (method, seed) a model vmapped in one jitted step
    (equal to single runs: ``tests/test_scale_out.py``). Each model's result is written as its own file; the
    lowest missing seed of every cell goes first."""
    if train_fn is None:
        from minsubdt_jax.train import train as train_fn
    from minsubdt_jax.agents import preset_config
    from minsubdt_jax.rundir import Interrupted, checkpoint_steps

    check_critic_settings(preset, methods)  # before anything is written
    out_dir = result_dir(variant(preset, costs), results_root)
    path = lambda e, d, m, s: os.path.join(out_dir, run_name(e, d, m, s) + ".json")  # noqa: E731
    own = lambda m: dict(physics=physics, costs=costs, **overrides)  # noqa: E731
    check_not_stale(path, [(e, d, m, s) for e in envs for d in datasets for m in methods for s in seeds],
                    lambda m: dataclasses.replace(preset_config(preset, m), **own(m)))
    os.makedirs(out_dir, exist_ok=True)
    todo, skipped = plan_units(envs, datasets, methods, seeds, path, whole_env)
    status = {"done": [], "skipped": skipped, "failed": []}
    for i, (first, dss, env, ms, n) in enumerate(todo):
        names = [run_name(env, d, m, s) for d in dss for m in ms for s in range(first, first + n)]
        label = "+".join(ms) + f" {env}-{'+'.join(dss)} s{first}" + (f"-{first + n - 1}" if n > 1 else "")
        suffix = f"-s{first}" if n == 1 else f"-s{first}-{first + n - 1}"
        cfg = dataclasses.replace(preset_config(preset, ",".join(ms)), env=env, dataset=",".join(dss), seed=first,
                                  seeds=n, **own(ms[0]),
                                  out=os.path.join(runs_root, variant(preset, costs),
                                                   f"{env}-{'+'.join(dss)}-{'+'.join(ms)}{suffix}"))
        log(f"[{i + 1}/{len(todo)}] {label} ...")
        t0 = time.time()
        try:
            # resumed where a checkpoint is (a program cut before its first one starts again)
            res = train_fn(cfg, resume=bool(checkpoint_steps(os.path.join(cfg.out, "checkpoints"))), verbose=False)
        except Interrupted:  # Ctrl-C stops the sweep, not only this unit (which resumes from its checkpoint)
            raise
        except Exception:  # one failed program must not stop the sweep; it is reported and retried next time
            log(traceback.format_exc())
            status["failed"] += names
            continue
        written, scores = write_unit(res, names, cfg.out, env, path)
        log(f"[{i + 1}/{len(todo)}] {label}: normalised {' '.join(scores)} ({time.time() - t0:.0f} s)")
        status["done"] += names
        if on_unit is not None:
            on_unit(written, f"{label}: normalised {' '.join(scores)}")
    return status


def write_unit(res: dict, names: list[str], run_dir: str, env: str, path) -> tuple[list[str], list[str]]:
    """One result file per model of a finished program (``res``: its results.json; ``names``: the models' run
    names, in the program's order), each with its training curve; ``(paths written, normalised scores)``."""
    from minsubdt_jax.rundir import write_atomic

    written, scores = [], []
    for j, name in enumerate(names):
        one = model_results(res, j)
        curve = model_curve(run_dir, one["config"])  # the model's method, seed and dataset
        one.update({"curve": curve} if curve else {})
        d, m, s = one["config"]["dataset"], one["config"]["method"], one["config"]["seed"]
        assert name == run_name(env, d, m, s), (name, d, m, s)
        written.append(path(env, d, m, s))
        write_atomic(written[-1], json.dumps(compact(one)))  # a result file is complete or absent
        scores.append(f"{one.get('eval', {}).get('normalized_score_mean', float('nan')):.1f}")
    return written, scores


def load_results(preset="cpu", results_root=RESULTS) -> list[dict]:
    rows = []
    for path in sorted(glob.glob(os.path.join(result_dir(preset, results_root), "*.json"))):
        with open(path) as f:
            r = json.load(f)
        c = r["config"]
        rows.append({"env": c["env"], "dataset": c["dataset"], "method": c["method"], "seed": c["seed"], "r": r})
    return rows


def summarise(preset: str, results_root=RESULTS) -> tuple[dict, list]:
    """The table of the results present at ``preset`` (no file written), and the result rows it came from."""
    rows = load_results(preset, results_root)
    cells = {}
    for row in rows:
        ev = row["r"].get("eval")
        if ev is None:
            continue
        c = cells.setdefault((row["dataset"], row["env"], row["method"]), {"scores": [], "seeds": [], "btd": [],
                                                                          "ms": [], "ms_demo": [], "lengths": []})
        c["scores"].append(ev["normalized_score_mean"])
        c["lengths"].append(ev["length_mean"])
        c["seeds"].append(row["seed"])
        c["btd"].append(ev["better_than_mean_demo_share"])
        c["ms"].append(ev["min_subdominance_mean"])
        c["ms_demo"].append(row["r"]["dataset"]["min_subdominance_mean"] if row["method"] == "minsubdt" else None)
    table = {}
    for (ds, env, m), c in cells.items():
        s, order = np.asarray(c["scores"]), np.argsort(c["seeds"])
        table.setdefault(f"{ds}/{env}", {})[m] = {
            "mean": float(s.mean()), "std": float(s.std()), "n_seeds": len(s), "seeds": sorted(c["seeds"]),
            "scores": [float(s[i]) for i in order], "lengths": [float(c["lengths"][i]) for i in order],
            "better_than_mean_demo_share": float(np.mean(c["btd"])), "rollout_min_subdominance": float(np.mean(c["ms"])),
        }
    averages = {}
    for label, keep in (("all", DATASETS), ("without medium-replay", ("medium-expert", "medium"))):
        for m in COLUMNS:
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
    files, demo = data_files(rows)
    episodes = sorted({r["r"]["eval"]["episodes"] for r in rows if "eval" in r["r"]})
    out = {"preset": preset, "eval_episodes": "/".join(map(str, episodes)) or "–", "runs": len(rows), "table": table,
           "averages": averages, "versus_dt": versus_dt(table), "dataset_score": demo,
           "cost_rank_agreement": costs, "data_files": files,
           "published_seed_table1_gym_d4rl": {f"{d}/{e}": dict(v, **PUBLISHED_BASELINES[d, e])
                                              for (d, e), v in PUBLISHED.items()}}
    return out, rows


def aggregate(preset="cpu", results_root=RESULTS, out_root=RESULTS, plots=True, runs_root="runs/table1") -> dict:
    """Writes table1.md / table1.json (and the cost plots, and the curves of the runs on this machine) from the
    results present, beside the DT-family table before the DT fix where it was kept; returns the table."""
    out, rows = summarise(preset, results_root)
    before = os.path.join(results_root, "table1", table1_compare.before_fix(preset))
    out["before_dt_fix"] = table1_compare.summary(summarise(table1_compare.before_fix(preset), results_root)[0]) \
        if os.path.isdir(before) else None
    os.makedirs(out_root, exist_ok=True)
    out["curves"] = plot_cell_curves(preset, runs_root, out_root, set(out["table"]), rows) if plots else {}
    with atomic_open(os.path.join(out_root, "table1.json")) as f:
        json.dump(out, f, indent=2)
    with atomic_open(os.path.join(out_root, "table1.md")) as f:
        f.write(markdown(out) + table1_seeds.markdown(out) + table1_compare.markdown(out))
    if plots and rows:
        for env in ENVS:
            plot_costs(rows, env, os.path.join(out_root, f"table1_costs_{env}.png"))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("action", nargs="?", default="all", choices=["all", "run", "aggregate"])
    p.add_argument("--preset", default="cpu")
    p.add_argument("--envs", nargs="+", default=list(ENVS), choices=ENVS)
    p.add_argument("--datasets", nargs="+", default=list(DATASETS), choices=DATASETS)
    p.add_argument("--methods", nargs="+", default=list(METHODS), choices=COLUMNS,
                   help="the seed's DT-family columns by default; the critic agents' (the seed's cql, bear, brac-v; "
                   "iql, td3bc; minsubdt-iql, ...) are run when named")
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    p.add_argument("--runs-root", default="runs/table1", help="training run directories (checkpoints)")
    p.add_argument("--physics", default="auto", choices=["auto", "mjx", "mujoco"],
                   help="who steps the recordings and evaluations (auto: C MuJoCo on a CPU, MJX on a GPU)")
    p.add_argument("--costs", default=None, help="cost metrics (minsubdt_jax.costs), comma-separated; default the "
                   "env's. Results and their table go to experiments/results/table1/<preset>-costs-<names>/")
    p.add_argument("--whole-env", action=argparse.BooleanOptionalAction, default=None,
                   help="train an env's datasets (all its methods x seeds) in one program (default: with --preset "
                   "paper, for a GPU)")
    p.add_argument("--precision", default="f32", choices=["f32", "tf32", "bf16"],
                   help="the matmul precision of every unit (the DT family's and, since issue 58, the critic "
                        "agents')")
    p.add_argument("--commit", action="store_true", help="git-commit each finished unit's result files, with the "
                   "command that resumes the sweep in the message")
    a = p.parse_args(argv)
    from minsubdt_jax.config import PRESETS
    from minsubdt_jax.rundir import Interrupted

    if a.preset not in PRESETS:
        p.error(f"--preset must be one of {list(PRESETS)}")
    if min(a.seeds) < 0 or len(set(a.seeds)) != len(a.seeds):
        p.error(f"--seeds must be >= 0, each once, got {a.seeds}")
    if a.costs is not None:
        from minsubdt_jax.costs import check_costs

        for env in a.envs:
            try:
                check_costs(env, a.costs)
            except ValueError as e:
                p.error(f"{env}: {e}")
    failed = []
    if a.action in ("all", "run"):
        whole = a.preset == "paper" if a.whole_env is None else a.whole_env
        resume = "python experiments/table1.py " + " ".join(argv if argv is not None else sys.argv[1:])
        on_unit = (lambda paths, what: commit_results(paths, f"Table 1 ({a.preset}): {what}; resume: {resume}")
                   ) if a.commit else None
        try:  # an unset critic agent or a stale result: one error before anything is written
            st = run_sweep(a.preset, a.envs, a.datasets, a.methods, a.seeds, a.runs_root, physics=a.physics,
                           costs=a.costs, whole_env=whole, on_unit=on_unit,
                           **({"precision": a.precision} if a.precision != "f32" else {}))
        except ValueError as e:
            p.error(str(e))
        except Interrupted:
            print(f"interrupted: the sweep stopped after a checkpoint of the unit under way; resume with: {resume}",
                  file=sys.stderr, flush=True)
            return 130
        print(f"done {len(st['done'])}, already there {len(st['skipped'])}, failed {len(st['failed'])}", flush=True)
        failed = st["failed"]
    if a.action in ("all", "aggregate"):
        name = variant(a.preset, a.costs)
        out = aggregate(name, out_root=RESULTS if a.costs is None else result_dir(name), runs_root=a.runs_root)
        print(markdown(out))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
