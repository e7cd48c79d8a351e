"""Table 1's figures: each model's training curve kept in its result file, a cell's curves drawn from those files
(or from this machine's run directories), and the demos' against the rollouts' cost features
(``experiments/table1.py aggregate``)."""

from __future__ import annotations

import glob
import os
import re

import numpy as np

from minsubdt_jax.methods import METHODS as ALL_METHODS

from table1_report import COLUMNS, DATASETS, ENVS, METHOD_NAMES
from minsubdt_jax.atomic import save_figure


def model_curve(run_dir: str, model: dict) -> dict | None:
    """One model's training curve from its program's ``metrics.jsonl`` (``model``: its ``method``, ``seed`` and,
    over several datasets, ``dataset``, as in results.json's ``models``): the evaluations' steps, normalised score
    and min-subdominance (means over their episodes; ``final`` marks the last), and its training loss per logged
    step. Kept in the model's result file, so a landed cell's curves outlive the machine that trained it; ``None``
    where the run directory has no evaluation."""
    from minsubdt_jax.rundir import per_model, read_metrics

    rows = read_metrics(os.path.join(run_dir, "metrics.jsonl"))
    evals = [r for r in rows if "eval_normalized_score" in r]
    if not evals:
        return None
    r0 = evals[0]
    k = next((i for i, (m, s) in enumerate(zip(r0["eval_method"], r0["eval_seed"]))
              if m == model["method"] and s == model["seed"]
              and ("eval_dataset" not in r0 or r0["eval_dataset"][i] == model.get("dataset"))), None)
    if k is None:
        raise ValueError(f"{run_dir}: metrics.jsonl evaluates no model {model} (another program's run directory?)")
    losses = [r for r in rows if per_model(r, "loss")]
    return {"step": [r["step"] for r in evals], "final": [bool(r.get("final", False)) for r in evals],
            "normalized_score": [r["eval_normalized_score"][k] for r in evals],
            "min_subdominance": [r["eval_min_subdominance"][k] for r in evals],
            "loss_step": [r["step"] for r in losses], "loss": [per_model(r, "loss")[k] for r in losses]}


def curves_from_results(rows: list[dict]) -> dict:
    """:func:`minsubdt_jax.plot.curves`' dict from the ``curve`` of committed result files (``rows``: one cell's,
    from ``table1.load_results``): per method, the mean and std over its seeds at each evaluation step."""
    have = [r for r in rows if r["r"].get("curve")]
    if len({_schedule(r) for r in have}) > 1:
        raise ValueError("curves_from_results: these result files come from programs with different evaluation or "
                         "loss steps; split them with programs_of first")
    out = {"score": {}, "min_subdominance": {}}
    steps, loss = have[0]["r"]["curve"]["loss_step"], np.array([r["r"]["curve"]["loss"] for r in have], float)
    out["loss"] = (np.array(steps), loss.mean(0), loss.std(0))
    for method in dict.fromkeys(r["method"] for r in have):
        cs = [r["r"]["curve"] for r in have if r["method"] == method]
        for key, name in (("normalized_score", "score"), ("min_subdominance", "min_subdominance")):
            v = np.array([c[key] for c in cs], float)
            out[name][method] = (np.array(cs[0]["step"]), v.mean(0), v.std(0), np.array(cs[0]["final"]))
    return out


def _schedule(row: dict) -> tuple:
    c = row["r"]["curve"]
    return tuple(c["step"]), tuple(c["loss_step"])


def programs_of(rows: list[dict]) -> dict[str, list[dict]]:
    """One cell's result rows with a ``curve``, grouped by their evaluation and loss steps (the DT family's 10k
    steps and each critic agent's own schedule cannot share one mean), each group labelled by its methods:
    ``{"iql": [...], "td3bc": [...]}``, the input for one :func:`curves_from_results` each. Two programs of the
    same methods on other schedules keep apart, the second labelled with its evaluation steps too."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        if r["r"].get("curve"):
            groups.setdefault(_schedule(r), []).append(r)
    out: dict[str, list[dict]] = {}
    for (steps, _), g in groups.items():
        label = "+".join(dict.fromkeys(r["method"] for r in g))
        out[label if label not in out else f"{label} (evaluated at {list(steps)})"] = g
    return out


def _methods_of(run_dir: str, prefix: str) -> list[str]:
    """The methods of a sweep's run directory ``<prefix><m1+m2...>-s<a>[-<b>]`` (none if it is not one: e.g.
    ``walker-medium-replay-...`` under the prefix ``walker-medium-``)."""
    m = re.fullmatch(re.escape(prefix) + r"(.+)-s\d+(-\d+)?", os.path.basename(run_dir))
    names = m.group(1).split("+") if m else []
    return names if names and all(n in ALL_METHODS for n in names) else []


def plot_cell_curves(preset: str, runs_root: str, out_root: str, landed, rows=()) -> dict:
    """Per landed cell (``landed``: "dataset/env" keys with results): its score and loss curves in one figure,
    ``out_root/table1_curves/<preset>-<env>-<dataset>.png``, drawn from the ``curve`` its result files keep
    (``rows``, :func:`load_results`: every seed and method of the cell, whichever machine trained it, so any clone
    draws the same figure), else from its training runs on this machine (``runs_root/<preset>/<env>-<dataset>-*``,
    their ``metrics.jsonl``: :func:`minsubdt_jax.plot.plot_runs`), else the figure already in ``out_root`` is kept.
    A cell still training gets no figure (the report would link one that is not committed).
    ``{"dataset/env": png path relative to out_root}``."""
    from minsubdt_jax.plot import plot_curves, plot_runs

    pngs = {}
    for env in ENVS:
        for ds in DATASETS:
            if f"{ds}/{env}" not in landed:
                continue
            rel = os.path.join("table1_curves", f"{preset}-{env}-{ds}.png")
            png = os.path.join(out_root, rel)
            kept = [r for r in rows if r["env"] == env and r["dataset"] == ds and r["r"].get("curve")]
            dirs = [] if kept else sorted(  # this machine's runs, only where no result file keeps a curve
                d for d in glob.glob(os.path.join(runs_root, preset, f"{env}-{ds}-*"))
                if os.path.exists(os.path.join(d, "metrics.jsonl")) and _methods_of(d, f"{env}-{ds}-"))
            if dirs or kept:
                os.makedirs(os.path.join(out_root, "table1_curves"), exist_ok=True)
            if kept:
                programs = programs_of(kept)
                plot_curves([curves_from_results(g) for g in programs.values()], png,
                            [f"{env}-{ds} {label} (result files)" for label in programs])
            elif dirs:
                plot_runs(dirs, png, labels=[os.path.basename(d).removeprefix(f"{env}-{ds}-") for d in dirs])
            if os.path.exists(png):
                pngs[f"{ds}/{env}"] = rel
    return pngs


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
                                      for m in COLUMNS if any(r["method"] == m for r in rs)]
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
    save_figure(fig, png)
    plt.close(fig)
