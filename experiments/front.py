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
per-seed means land in ``experiments/results/front/<cell>.json`` as they finish (commit it). A cell whose file
holds all of it is not run again, on any machine.

``report``: per cell, the hypervolume (moocore; reference point 1 in both costs, lower is better) of the non-dominated
points of the demos, of the scalar runs' means, and of each vector method's target sweep (the means over seeds per
target; and per seed, mean +- std), the Spearman per metric between the target and the achieved cost over the grid
and within its rows (the other metric's target held), and a figure of the demos and the rollout means in the plane
of the two costs.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results", "front")
PAIR = ("x_velocity", "energy@lived")
RUNS = {"vec": ("minsubdt-vec,dt-vec", ",".join(PAIR)), "minsubdt-x_velocity": ("minsubdt", PAIR[0]),
        "minsubdt-energy@lived": ("minsubdt", PAIR[1]), "minsubdt-both": ("minsubdt", ",".join(PAIR))}
VECTOR = ("minsubdt-vec", "dt-vec")


def cell_name(a) -> str:
    return f"{a.env}-{a.dataset}" + (f"-{a.tag}" if a.tag else "")


def train_runs(a, names) -> dict:
    """Train (or resume, or skip when finished) the runs ``names`` of a cell; their directories."""
    from minsubdt_jax.agents import preset_config
    from minsubdt_jax.config import validate
    from minsubdt_jax.rundir import checkpoint_steps
    from minsubdt_jax.train import train

    dirs = {}
    for name in names:
        methods, costs = RUNS[name]
        out = os.path.join(a.runs_root, cell_name(a), name)
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


def means(per_seed: list[dict]) -> dict:
    """Per seed: the mean normalised score and the mean of each cost over its episodes."""
    return {"normalized": [e["normalized_score_mean"] for e in per_seed],
            "costs": [[e["costs_mean"][m] for m in PAIR] for e in per_seed]}


def complete(out: dict, a) -> bool:
    """Whether a cell's results file ``out`` holds all the work of ``a``: every target of the grid for both vector
    methods, and every scalar run."""
    if not out.get("demo_costs"):  # (its preset, seeds and episodes are a's: check_args)
        return False
    demo, sweeps = np.asarray(out["demo_costs"]), out.get("sweeps", {})
    targets_done = all(any(r["target"] == t for r in sweeps.get(m, [])) for m in VECTOR
                       for t in grid_targets(m, demo, out["beta"], a.grid))
    return targets_done and set(RUNS) - {"vec"} <= set(out.get("scalar", {}))


def cell_file(a) -> tuple[str, dict]:
    """The cell's results file: its path, and what it holds so far (``{}`` before its first target)."""
    path = os.path.join(RESULTS, cell_name(a) + ".json")
    if not os.path.exists(path):
        return path, {}
    with open(path) as f:
        return path, json.load(f)


def run(a, path: str, out: dict) -> None:
    """Trains what the cell ``a`` lacks and adds each finished target and scalar run to ``out`` (what its results
    file at ``path`` holds so far), saving it after each."""
    from minsubdt_jax.atomic import write_atomic
    from minsubdt_jax.evaluate import evaluate_run, load_run

    if complete(out, a):  # its run directories may be on another machine: nothing to train again
        print(f"{path}: complete (every target and scalar run); nothing to do", flush=True)
        return
    dirs = train_runs(a, ["vec"])  # the vector methods and their sweeps first, the scalar runs after
    os.makedirs(RESULTS, exist_ok=True)
    loaded = load_run(dirs["vec"])
    demo = loaded.per_model[0].costs
    out.update({"cell": cell_name(a), "env": a.env, "dataset": a.dataset, "preset": a.preset, "seeds": a.seeds,
                "episodes": a.episodes, "beta": loaded.cfg.beta, "metrics": list(PAIR),
                "dataset_sha256": loaded.per_model[0].source.sha256, "demo_costs": demo.tolist(),
                "command": "python experiments/front.py run " + " ".join(sys.argv[2:])})

    def save():
        write_atomic(path, json.dumps(out, indent=1))

    for method in VECTOR:
        done = out.setdefault("sweeps", {}).setdefault(method, [])
        for target in grid_targets(method, demo, loaded.cfg.beta, a.grid):
            if any(r["target"] == target for r in done):
                continue
            ev = evaluate_run(dirs["vec"], target, a.episodes, method, run=loaded)
            done.append({"target": target, **means(ev["eval_per_seed"])})
            c = np.mean(done[-1]["costs"], 0)
            print(f"{method} {target}: costs {c[0]:.3f}, {c[1]:.3f}; normalised "
                  f"{np.mean(done[-1]['normalized']):.1f}", flush=True)
            save()
    for name in RUNS:
        if name != "vec":
            res_dir = train_runs(a, [name])[name]
            with open(os.path.join(res_dir, "results.json")) as f:
                out.setdefault("scalar", {})[name] = means(json.load(f)["eval_per_seed"])
            save()


def hypervolume(points) -> float:
    """Hypervolume dominated by ``points [n, 2]`` (costs, lower is better) up to the reference point (1, 1),
    clipped into [0, 1] (moocore: it keeps the non-dominated points itself)."""
    try:
        import moocore
    except ImportError:
        raise SystemExit("the hypervolume needs moocore: pip install -e '.[front]'") from None
    p = np.clip(np.asarray(points, np.float64).reshape(-1, 2), 0.0, 1.0)
    return float(moocore.hypervolume(p, ref=[1.0, 1.0]))


def steering(t, c, k: int, held: bool = False) -> float:
    """How metric ``k``'s target steers its achieved cost: the Spearman between the two over the whole grid, or with
    ``held`` within each group of targets that share the other metric's target; mean over the groups and seeds.
    ``t [n, 2]`` the targets, ``c [n, seeds, 2]`` the achieved costs."""
    from minsubdt_jax.costs import spearman

    group = t[:, 1 - k] if held else np.zeros(len(t))
    return float(np.mean([spearman(t[group == v, k], c[group == v, s, k])
                          for v in np.unique(group) for s in range(c.shape[1])]))


def cell_report(r: dict) -> tuple[list[str], dict]:
    rows, notes, pts = [], [], {"demos": np.asarray(r["demo_costs"])}
    rows.append(f"| demos ({len(r['demo_costs'])} episodes) | {hypervolume(pts['demos']):.3f} | – | – | – | – | – |")
    if r.get("scalar"):
        scal = np.array([np.mean(v["costs"], 0) for v in r["scalar"].values()])
        pts["scalar MinSubDT"] = scal
        per = np.array([[hypervolume([np.asarray(v["costs"])[s] for v in r["scalar"].values()])
                         for s in range(r["seeds"])]])
        rows.append(f"| scalar MinSubDT ({', '.join(k.removeprefix('minsubdt-') for k in r['scalar'])}) | "
                    f"{hypervolume(scal):.3f} | {per.mean():.3f} ± {per.std():.3f} | – | – | – | – |")
    for method, sweep in r.get("sweeps", {}).items():
        c = np.array([s["costs"] for s in sweep])  # [targets, seeds, 2]
        t = np.array([[s["target"][m] for m in PAIR] for s in sweep])
        pts[method] = c.mean(1)
        hv_seed = np.array([hypervolume(c[:, s]) for s in range(c.shape[1])])
        rho, held = ([steering(t, c, k, h) for k in range(2)] for h in (False, True))
        rows.append(f"| `{method}` ({len(sweep)} targets) | {hypervolume(c.mean(1)):.3f} | {hv_seed.mean():.3f} ± "
                    f"{hv_seed.std():.3f} | {rho[0]:+.2f} | {rho[1]:+.2f} | {held[0]:+.2f} | {held[1]:+.2f} |")
        notes.append(beyond_demos(method, c.mean(1), pts["demos"]))
    head = [f"### {r['cell']} ({r['preset']}, {r['seeds']} seeds x {r['episodes']} episodes per target)", "",
            f"`{r['command']}`", "",
            f"| points | hypervolume of the means | per seed | Spearman(target, cost) {PAIR[0]} | {PAIR[1]} | "
            f"other target held: {PAIR[0]} | {PAIR[1]} |", "|---|---|---|---|---|---|---|"]
    return head + rows + ["", demos_trade_off(pts["demos"]), ""] + [x for n in notes if n for x in (n, "")], pts


def beyond_demos(method: str, means, d) -> str:
    """The targets whose rollouts spend less in a metric than every demo, ``means [targets, 2]`` their mean costs
    and ``d [n, 2]`` the demos': how many, and their mean cost in the other metric."""
    out = []
    for k in range(2):
        below = means[:, k] < d[:, k].min()
        if below.any():
            out.append(f"{below.sum()} of {len(means)} targets below every demo's {PAIR[k]} cost ({d[:, k].min():.3f}; "
                       f"theirs {means[below, k].mean():.3f}, at {PAIR[1 - k]} cost {means[below, 1 - k].mean():.3f})")
    return f"`{method}`: " + "; ".join(out) + "." if out else ""


def demos_trade_off(d) -> str:
    """What the data offers the targets, ``d [n, 2]`` the demos' costs: how the two costs go together, and how
    fast the tenth of the demos that spends least in the second metric is (what a frugal token asks for)."""
    from minsubdt_jax.costs import spearman

    tenth = np.argsort(d[:, 1], kind="stable")[:max(len(d) // 10, 1)]
    return (f"The demos' two costs: Spearman {spearman(d[:, 0], d[:, 1]):+.2f}; the tenth that spends least "
            f"{PAIR[1]} ({PAIR[1]} cost {d[tenth, 1].mean():.3f}) has {PAIR[0]} cost {d[tenth, 0].mean():.3f} "
            f"(all demos {d[:, 0].min():.3f}-{d[:, 0].max():.3f}).")


def report(a) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = sorted(f for f in os.listdir(RESULTS) if f.endswith(".json")) if os.path.isdir(RESULTS) else []
    if not files:
        raise SystemExit(f"no results under {RESULTS}: run `python experiments/front.py run` first")
    lines = ["# Fronts in metric space (issue 55)", "", "Generated by `python experiments/front.py report` from "
             "`experiments/results/front/*.json`. Costs are lower-is-better, in [0, 1]; the hypervolume is the area "
             f"the points dominate up to (1, 1) in ({', '.join(PAIR)}), computed by moocore. Spearman: over the "
             "target grid, between the target in a metric and the achieved cost in it (mean over seeds; +1: the "
             "target steers that metric perfectly); *other target held*: the same within each row of the grid that "
             "shares the other metric's target, mean over those rows and the seeds (a metric that steers only where "
             "the other's target allows it scores low over the whole grid and high here). The demos' points are "
             "single episodes; a method's point is the mean of one target's rollouts (3 seeds x its episodes), so the "
             "demos' front holds the spread of single episodes and the methods' fronts do not: compare the fronts' "
             "shapes in the figure as well as the numbers.", ""]
    fig, axes = plt.subplots(1, len(files), figsize=(6 * len(files), 5), squeeze=False)
    for ax, f in zip(axes[0], files):
        with open(os.path.join(RESULTS, f)) as fh:
            r = json.load(fh)
        text, pts = cell_report(r)
        lines += text
        for (label, p), style in zip(pts.items(), ("o", "s", "^", "v")):
            ax.scatter(p[:, 0], p[:, 1], s=8 if label == "demos" else 30, marker=style, alpha=0.35 if label ==
                       "demos" else 0.9, label=label)
        ax.set(xlabel=f"{PAIR[0]} cost", ylabel=f"{PAIR[1]} cost", title=r["cell"])
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(HERE, "results", "front.png"), dpi=110)
    lines += ["![the demos and the rollout means](front.png)", ""]
    with open(os.path.join(HERE, "results", "front.md"), "w") as f:
        f.write("\n".join(lines))
    print("\n".join(lines))


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


if __name__ == "__main__":
    main()
