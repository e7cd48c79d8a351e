"""Fronts in metric space (issue 55): does a target per metric choose the trade-off, and is the front it traces better
than the demos'?

    python experiments/front.py run --env walker --dataset medium-replay     # trains, sweeps targets (resumable)
    python experiments/front.py report                                       # experiments/results/front.{md,png}

``run`` trains, at the ``study`` preset with ``--seeds`` seeds, on the metrics ``x_velocity`` and ``energy@lived``
(forward speed and control energy, MO-Gymnasium's two objectives; ``energy@lived`` does not charge a fall, so it
is not survival again): ``minsubdt-vec`` and ``dt-vec`` in one program, and the scalar ``minsubdt`` three times, on
each metric alone and on both (each scored on both: ``--eval-costs``). Then it rolls out each vector method over a
``--grid`` x ``--grid`` grid of targets (``minsubdt-vec``: eq. 2's per-metric term from 0 to beta; ``dt-vec``: each
metric's cost from the demos' best to their worst), ``--episodes`` episodes per seed and target
(:func:`minsubdt_jax.evaluate.evaluate_run`). Runs live in ``runs/front/<cell>/`` and resume; each target's
per-seed means land in ``experiments/results/front/<cell>.json`` as they finish (the file says ``partial`` until
it holds every target and scalar run; the report gives no numbers of such a cell). A cell whose file holds all of it
is not run again, on any machine; ``--commit`` commits the file as each part lands (the sweeps
once both are done). A file holding part of a sweep is finished only by the vector run it came from (same
recording): on another machine, or after another training, ``run`` refuses with one error line.

``report``: the hypervolumes, the steering Spearman and the figure (``experiments/front_report.py``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import sys

import numpy as np

from front_report import PAIR, RESULTS, report  # beside this file: the report reads what run writes
RUNS = {"vec": ("minsubdt-vec,dt-vec", ",".join(PAIR)), "minsubdt-x_velocity": ("minsubdt", PAIR[0]),
        "minsubdt-energy@lived": ("minsubdt", PAIR[1]), "minsubdt-both": ("minsubdt", ",".join(PAIR))}
VECTOR = ("minsubdt-vec", "dt-vec")


def cell_name(a) -> str:
    return f"{a.env}-{a.dataset}" + (f"-{a.tag}" if a.tag else "")


def run_dir(a, name: str) -> str:
    """Where the run ``name`` (a key of ``RUNS``) of cell ``a`` lives."""
    return os.path.join(a.runs_root, cell_name(a), name)


def train_runs(a, names) -> dict:
    """Train (or resume, or skip when finished) the runs ``names`` of a cell; their directories."""
    from minsubdt_jax.agents import preset_config
    from minsubdt_jax.config import validate
    from minsubdt_jax.rundir import checkpoint_steps
    from minsubdt_jax.train import train

    dirs = {}
    for name in names:
        methods, costs = RUNS[name]
        out = run_dir(a, name)
        dirs[name] = out
        if os.path.exists(os.path.join(out, "results.json")):
            continue
        cfg = dataclasses.replace(preset_config(a.preset, methods), env=a.env, dataset=a.dataset, seeds=a.seeds,
                                  costs=costs, eval_costs=",".join(PAIR), out=out, **({"steps": a.steps} if a.steps
                                                                                     else {}))
        print(f"== {name}: {methods} on {costs} -> {out}", flush=True)
        if os.path.exists(out) and not checkpoint_steps(os.path.join(out, "checkpoints")):
            shutil.rmtree(out)  # a run cut before its first checkpoint holds nothing to resume
        train(validate(cfg), resume=os.path.exists(out))
    return dirs


def grid_targets(method: str, demo_costs: np.ndarray, beta: float, n: int) -> list[dict]:
    """``n x n`` targets: eq. 2's per-metric term in [0, beta] (``minsubdt-vec``) or each metric's cost from the
    demos' best to their worst (``dt-vec``)."""
    if method == "minsubdt-vec":
        axes = [np.linspace(0.0, beta, n)] * 2
    else:
        axes = [np.linspace(demo_costs[:, k].min(), demo_costs[:, k].max(), n) for k in range(2)]
    return [{PAIR[0]: round(float(x), 4), PAIR[1]: round(float(y), 4)} for x in axes[0] for y in axes[1]]


def means(res: dict) -> dict:
    """Per model of a run's results (or an evaluation's): the mean normalised score and the mean of each cost over
    its episodes."""
    from minsubdt_jax.rundir import per_model

    return {"normalized": [e["normalized_score_mean"] for e in per_model(res)],
            "costs": [[e["costs_mean"][m] for m in PAIR] for e in per_model(res)]}


def sweeps_done(out: dict, a) -> bool:
    """Whether a cell's results file ``out`` holds every target of ``a``'s grid for both vector methods (its preset,
    seeds and episodes are a's: check_args)."""
    if not out.get("demo_costs"):
        return False
    demo, sweeps = np.asarray(out["demo_costs"]), out.get("sweeps", {})
    return all(any(r["target"] == t for r in sweeps.get(m, [])) for m in VECTOR
               for t in grid_targets(m, demo, out["beta"], a.grid))


def scalar_missing(out: dict) -> list[str]:
    """The scalar runs a cell's results file ``out`` does not hold yet, in ``RUNS``' order."""
    return [n for n in RUNS if n != "vec" and n not in out.get("scalar", {})]


def complete(out: dict, a) -> bool:
    """Whether a cell's results file ``out`` holds all the work of ``a``: every target, every scalar run."""
    return sweeps_done(out, a) and not scalar_missing(out)


def cell_file(a) -> tuple[str, dict]:
    """The cell's results file: its path, and what it holds so far (``{}`` before its first target)."""
    path = os.path.join(RESULTS, cell_name(a) + ".json")
    if not os.path.exists(path):
        return path, {}
    with open(path) as f:
        return path, json.load(f)


def run(a, path: str, out: dict) -> None:
    """Trains what the cell ``a`` lacks and adds each finished target and scalar run to ``out`` (what its results
    file at ``path`` holds so far), saving it after each. What the file holds is not trained again: its run
    directories may be on another machine."""
    from minsubdt_jax.atomic import write_atomic

    if complete(out, a):
        print(f"{path}: complete (every target and scalar run); nothing to do", flush=True)
        return
    os.makedirs(RESULTS, exist_ok=True)

    def save():  # the file says whether it holds all of the cell (the report gives no numbers of a partial one)
        out["partial"] = not complete(out, a)
        write_atomic(path, json.dumps(out, indent=1))

    def landed(what: str):  # --commit: the cell file alone, as each part lands (a machine may vanish mid-cell)
        if a.commit:
            from gitcommit import commit_results
            commit_results([path], f"Front (issue 55), {cell_name(a)}: {what} landed; resume: bash "
                                   "experiments/queue.sh front")

    if not sweeps_done(out, a):  # the vector methods and their sweeps first, the scalar runs after
        sweep(a, out, save)
        landed("the target sweeps")
    for name in scalar_missing(out):
        res_dir = train_runs(a, [name])[name]
        with open(os.path.join(res_dir, "results.json")) as f:
            res = json.load(f)  # its recording's hash: another machine may record another file of the recipe
        out.setdefault("scalar", {})[name] = {**means(res), "dataset_sha256": res["dataset"]["sha256"]}
        save()
        landed(name)


def sweep(a, out: dict, save) -> None:
    """Trains (or resumes) the vector methods of cell ``a`` and rolls out each target of the grid that ``out`` lacks,
    calling ``save`` after each."""
    from minsubdt_jax.evaluate import evaluate_run, load_run

    vec = train_runs(a, ["vec"])["vec"]
    loaded = load_run(vec)
    demo = loaded.per_model[0].costs
    out.update({"cell": cell_name(a), "env": a.env, "dataset": a.dataset, "preset": a.preset, "seeds": a.seeds,
                "episodes": a.episodes, "beta": loaded.cfg.beta, "metrics": list(PAIR),
                "dataset_sha256": loaded.per_model[0].source.sha256, "demo_costs": demo.tolist(),
                "command": " ".join(["python experiments/front.py run",
                                     *(x for x in sys.argv[2:] if x != "--commit")])})  # what reruns it
    for method in VECTOR:
        done = out.setdefault("sweeps", {}).setdefault(method, [])
        for target in grid_targets(method, demo, loaded.cfg.beta, a.grid):
            if any(r["target"] == target for r in done):
                continue
            ev = evaluate_run(vec, target, a.episodes, method, run=loaded)
            done.append({"target": target, **means(ev)})
            c = np.mean(done[-1]["costs"], 0)
            print(f"{method} {target}: costs {c[0]:.3f}, {c[1]:.3f}; normalised "
                  f"{np.mean(done[-1]['normalized']):.1f}", flush=True)
            save()


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("--env", default="walker")
    r.add_argument("--dataset", default="medium-replay")
    r.add_argument("--preset", default="study")
    r.add_argument("--steps", type=int, default=None, help="override the preset's steps (a first look)")
    r.add_argument("--seeds", type=int, default=3)
    r.add_argument("--episodes", type=int, default=100)
    r.add_argument("--grid", type=int, default=5)
    r.add_argument("--tag", default="", help="names the results apart (a cheaper first look)")
    r.add_argument("--runs-root", default="runs/front")
    r.add_argument("--commit", action="store_true", help="git-commit the cell's results file when its target sweeps "
                   "are done and after each scalar run (its other files stay as they are)")
    sub.add_parser("report")
    a = p.parse_args(argv)
    if a.cmd == "report":
        return report(a)
    try:
        path, made = cell_file(a)
        check_args(a, path, made)
        run(a, path, made)
    except ValueError as e:  # a bad setting, or one the training refuses: one line, nothing written
        p.error(str(e))


def check_args(a, path: str, made: dict) -> None:
    """One ValueError on a setting ``run`` cannot use, before anything is trained or written; among them settings
    other than those the cell's results file (``made``, at ``path``) was made with (they would be rewritten beside
    its measured targets)."""
    from minsubdt_jax.config import PRESETS
    from minsubdt_jax.data import NAMED_DATASETS
    from minsubdt_jax.envs import ENVS

    if a.preset not in PRESETS:
        raise ValueError(f"--preset must be one of {list(PRESETS)}, got {a.preset!r}")
    if a.env not in ENVS:
        raise ValueError(f"--env must be one of {list(ENVS)}, got {a.env!r}")
    if a.dataset not in NAMED_DATASETS:
        raise ValueError(f"--dataset must be one of {list(NAMED_DATASETS)}, got {a.dataset!r}")
    for name, low in (("seeds", 1), ("episodes", 1), ("grid", 2), ("steps", 1)):
        v = getattr(a, name)
        if v is not None and v < low:
            raise ValueError(f"--{name} must be {'> 0' if low == 1 else f'>= {low}'}, got {v}")
    differ = {k: made[k] for k in ("preset", "seeds", "episodes") if k in made and made[k] != getattr(a, k)}
    if differ:
        raise ValueError(f"{path} was made with " + " ".join(f"--{k} {v}" for k, v in differ.items())
                         + ": give the same, or --tag NAME for a cell file of its own")
    check_part_sweep(a, path, made)


def check_part_sweep(a, path: str, made: dict) -> None:
    """One ValueError where the cell's file holds some targets but not all, and this machine's vector run is not
    the one they came from (absent, or trained on another recording): finishing the sweep with other models would
    put the targets of two trainings in one front. (Targets are saved as they land; the file is committed once
    both sweeps are done.)"""
    n = sum(len(v) for v in made.get("sweeps", {}).values())
    if not n or sweeps_done(made, a):
        return
    vec = run_dir(a, "vec")
    if not os.path.exists(os.path.join(vec, "results.json")):
        raise ValueError(f"{path} holds {n} targets rolled out from vector models that {vec} does not hold: sweep "
                         "on the machine that does, or move the file's sweeps aside to sweep again")
    with open(os.path.join(vec, "results.json")) as f:
        sha = json.load(f)["dataset"]["sha256"]
    if sha != made.get("dataset_sha256"):
        raise ValueError(f"{path} holds {n} targets of vector models trained on the recording "
                         f"{str(made.get('dataset_sha256'))[:12]}; {vec} trained on {sha[:12]}: move the file's "
                         "sweeps aside to sweep again")


if __name__ == "__main__":
    main()
