"""Several runs in one figure: ``python -m minsubdt_jax.plot RUN_DIR [RUN_DIR ...] --out runs.png``.

Reads each run directory's ``metrics.jsonl`` and draws, against the gradient step, the training loss and the
normalised score of every (run, method): the mean over its seeds with a ± std band (the final evaluation as a
star), and min-subdominance against the demos. Runs of several methods or seeds (``--method a,b --seeds S``)
give one line per method. As ``d3rlpy plot`` does for its logs.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

from .rundir import exit_code, model_labels, per_model, read_metrics
from .atomic import save_figure


def curves(run_dir: str) -> dict:
    """``{"loss": (steps, mean, std), "score": {method: (steps, mean, std, final)}, "min_subdominance": ...}`` of
    one run directory; raises ValueError where it holds no ``metrics.jsonl``."""
    path = os.path.join(run_dir, "metrics.jsonl")
    if not os.path.exists(path):
        raise ValueError(f"{run_dir}: no metrics.jsonl (not a run directory of python -m minsubdt_jax.train)")
    rows = read_metrics(path)
    losses = [r for r in rows if "loss" in r]
    per = np.array([(per_model(r, "loss") or [r["loss"]]) for r in losses], float)
    out = {"loss": (np.array([r["step"] for r in losses]), per.mean(1), per.std(1)), "score": {},
           "min_subdominance": {}}
    evals = [r for r in rows if "eval_normalized_score" in r]
    for key, name in (("eval_normalized_score", "score"), ("eval_min_subdominance", "min_subdominance")):
        for method in dict.fromkeys(m for r in evals for m in model_labels(r, len(r[key]))):
            pts = [(r["step"], [v for m, v in zip(model_labels(r, len(r[key])), r[key]) if m == method],
                    r.get("final", False)) for r in evals]
            out[name][method] = (np.array([p[0] for p in pts]), np.array([np.mean(p[1]) for p in pts]),
                                 np.array([np.std(p[1]) for p in pts]), np.array([p[2] for p in pts]))
    return out


def plot_runs(run_dirs: list[str], png: str, labels: list[str] | None = None) -> None:
    """Writes ``png``: loss, normalised score and min-subdominance of ``run_dirs`` (see the module docstring)."""
    data = [curves(d) for d in run_dirs]  # every directory checked before anything is drawn
    plot_curves(data, png, labels or [os.path.basename(os.path.normpath(d)) for d in run_dirs])


def plot_curves(data: list[dict], png: str, labels: list[str]) -> None:
    """Writes ``png`` from :func:`curves`' dicts (one per label), however they were gathered."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4), dpi=100)
    k = 0
    for label, c in zip(labels, data):
        steps, mean, std = c["loss"]
        axes[0].plot(steps, mean, color=f"C{k % 10}", label=label)
        axes[0].fill_between(steps, mean - std, mean + std, color=f"C{k % 10}", alpha=0.2)
        for method in c["score"]:
            color = f"C{k % 10}"
            name = label if len(c["score"]) == 1 else f"{label}: {method}"
            for ax, key in ((axes[1], "score"), (axes[2], "min_subdominance")):
                s, m, sd, final = c[key][method]
                ax.plot(s, m, marker="o", ms=3, color=color, label=name)
                ax.fill_between(s, m - sd, m + sd, color=color, alpha=0.2)
                ax.plot(s[final], m[final], "*", color=color, ms=11)
            k += 1
        k += 0 if c["score"] else 1
    axes[0].set(xlabel="gradient step", ylabel="training loss", yscale="log")
    axes[1].set(xlabel="gradient step", ylabel="normalised score")
    axes[2].set(xlabel="gradient step", ylabel="min-subdominance vs demos")
    for ax, title in zip(axes, ("loss (mean ± std over seeds)", "normalised score (★ final)", "min-subdominance")):
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=7, loc="best")
    fig.tight_layout()
    save_figure(fig, png)
    plt.close(fig)


def plot_learning_curve(metrics_path: str, png_path: str, title: str | None = None) -> None:
    """From ``metrics.jsonl``: the training loss against step and, when the log holds evaluations, the normalised
    score and min-subdominance against step, one line per method (mean over its seeds, band from the lowest to
    the highest seed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = read_metrics(metrics_path)
    losses = [r for r in rows if "loss" in r]
    evals = [r for r in rows if "eval_normalized_score" in r]
    fig, axes = plt.subplots(1, 3 if evals else 1, figsize=(13 if evals else 5, 3.2), dpi=100, squeeze=False)
    ax = axes[0, 0]
    ax.plot([r["step"] for r in losses], [r["loss"] for r in losses], marker=".")
    ax.set(xlabel="gradient step", ylabel="training loss", yscale="log")
    ax.set_title("loss\n ", fontsize=10)
    for ax, key, title in [(a, k, t) for a, (k, t) in zip(axes[0, 1:], [
            ("eval_normalized_score", "normalised score"), ("eval_min_subdominance", "min-subdominance vs demos")])]:
        steps = [r["step"] for r in evals]
        v = np.array([r[key] for r in evals], float)  # [evaluations, models]
        names = model_labels(evals[0], v.shape[1])
        final = [i for i, r in enumerate(evals) if r.get("final")]
        for name in dict.fromkeys(names):
            cols = [j for j, n in enumerate(names) if n == name]
            w = v[:, cols]
            ax.plot(steps, w.mean(1), marker="o", label=name if len(set(names)) > 1 else None)
            ax.fill_between(steps, w.min(1), w.max(1), alpha=0.25)
            ax.plot([steps[i] for i in final], w.mean(1)[final], "k*", markersize=10)
        n = v.shape[1] // len(set(names))
        ax.set_xlabel("gradient step")
        ax.set_title(f"{title}\n★ final evaluation; {n} seed{'s' if n > 1 else ''}", fontsize=10)
        if len(set(names)) > 1:
            ax.legend(loc="best", fontsize=8)
    for ax in axes[0]:
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    save_figure(fig, png_path)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m minsubdt_jax.plot", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="+", help="run directories (python -m minsubdt_jax.train --out)")
    p.add_argument("--out", default="runs.png", help="the PNG to write (default runs.png)")
    p.add_argument("--labels", default=None, help="comma-separated labels, one per run (default: the folder names)")
    a = p.parse_args(argv)

    def run():
        labels = a.labels.split(",") if a.labels else None
        if labels is not None and len(labels) != len(a.runs):
            raise ValueError(f"--labels has {len(labels)} labels for {len(a.runs)} runs")
        folder = os.path.dirname(os.path.abspath(a.out))
        if not os.path.isdir(folder):
            raise ValueError(f"--out {a.out}: the folder {folder} does not exist")
        plot_runs(a.runs, a.out, labels)
        print(f"wrote {a.out}")

    return exit_code(run)


if __name__ == "__main__":
    sys.exit(main())
