"""The score curves' report: per curve its noise (between seeds, within a seed, from checkpoint to checkpoint), its
figure, and ``experiments/results/curves.md``, from the JSON files ``experiments/curves.py run`` writes."""

from __future__ import annotations

import dataclasses
import json
import os

import numpy as np
from minsubdt_jax.atomic import atomic_open, save_figure

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results", "curves")
FLAT_POINTS = 3.0  # issue 25: the 3-seed mean changes by <= 3 points over the last third
UNRESOLVED_SE = 10.0  # a fit this loose could hide a 20-point change (a seed's collapse on walker) within 2 SE


def noise(curve: dict) -> list[dict]:
    """Per method and evaluation step: the mean over seeds, the std between seed means, the mean standard error of
    one seed's mean (episode noise), and the seeds n (at this step's episodes) for 2 std / sqrt(n) <= 3 points."""
    rows = []
    for method in dict.fromkeys(m["method"] for m in curve["models"]):
        ms = [m for m in curve["models"] if m["method"] == method]
        for j, step in enumerate(curve["steps"]):
            means = np.array([m["mean"][j] for m in ms])
            if not np.isfinite(means).all():
                continue
            se = np.array([m["std"][j] for m in ms]) / np.sqrt(curve["episodes"][j])
            between = float(means.std(ddof=1)) if len(ms) > 1 else float("nan")
            rows.append({"method": method, "step": step, "episodes": curve["episodes"][j], "seeds": len(ms),
                         "mean": float(means.mean()), "between_seeds_std": between,
                         "episode_se": float(np.sqrt(np.mean(se ** 2))),
                         "seeds_for_3_points": (int(np.ceil((2 * between / FLAT_POINTS) ** 2))
                                                if np.isfinite(between) else None)})
    return rows


def stability(curve: dict) -> list[dict]:
    """Per method, over the evaluations of the curve's last third (periodic ones): the std of one seed's score from
    checkpoint to checkpoint (its mean over seeds), against the episode noise of one evaluation, and the mean over
    the last-third evaluations per seed (mean ± std over seeds): an average over checkpoints."""
    steps = np.array(curve["steps"], float)
    last = steps >= steps.max() * 2 / 3
    rows = []
    for method in dict.fromkeys(m["method"] for m in curve["models"]):
        ms = [m for m in curve["models"] if m["method"] == method]
        M = np.array([m["mean"] for m in ms], float)[:, last]
        keep = np.isfinite(M).all(0)
        M = M[:, keep]
        if M.shape[1] < 2:
            continue
        se = np.array([m["std"] for m in ms], float)[:, last][:, keep] / np.sqrt(np.array(curve["episodes"])[last][keep])
        avg = M.mean(1)
        rows.append({"method": method, "evaluations": int(M.shape[1]), "from_step": int(steps[last][keep][0]),
                     "checkpoint_std": float(M.std(1, ddof=1).mean()), "episode_se": float(np.sqrt((se ** 2).mean())),
                     "last_third_mean": float(avg.mean()),
                     "last_third_between_seeds": float(avg.std(ddof=1)) if len(avg) > 1 else float("nan"),
                     "first_to_last": float(M[:, -1].mean() - M[:, 0].mean()),
                     **dict(zip(("fitted_change", "fitted_change_se"), trend(steps[last][keep], M)))})
    return rows


def flat_verdict(change: float, se: float) -> str:
    """Issue 25's criterion on a fitted change over the last third (:func:`trend`): ``"yes"`` within ±3 points,
    ``"no"`` beyond, ``"unresolved"`` within but with a standard error above 10 points, where seeds swinging by
    tens of points between checkpoints leave a near-zero slope that shows nothing."""
    if abs(change) > FLAT_POINTS:
        return "no"
    return "yes" if se <= UNRESOLVED_SE else "unresolved"  # a NaN SE (no residual dof) is unresolved


def trend(steps: np.ndarray, scores: np.ndarray) -> tuple[float, float]:
    """The change of a method's score over ``steps`` estimated from every checkpoint, not from two: a least-squares
    line with one intercept per seed and a common slope, fitted to ``scores`` ``[S, E]`` (seed x evaluation).
    Returns the slope times the span of ``steps`` and its standard error (residual variance over S*E - S - 1
    degrees of freedom). With one seed it is an ordinary straight-line fit; balanced, the slope is that of the
    mean curve."""
    x = np.asarray(steps, float) - np.mean(steps)
    y = scores - scores.mean(1, keepdims=True)
    sxx = scores.shape[0] * (x ** 2).sum()
    b = float((y * x).sum() / sxx)
    dof = scores.size - scores.shape[0] - 1
    se = float(np.sqrt(((y - b * x) ** 2).sum() / dof / sxx)) if dof > 0 else float("nan")
    span = float(np.ptp(steps))
    return b * span, se * span


def pool_key(c: dict, default: dict) -> str:
    """What a curve file must share with another to pool their seeds: the data's hash, the DT's revision where a DT
    trained, the env and dataset, and every config field that changes what its agents learn
    (``minsubdt_jax.agents.result_fields``: BRAC-v at alpha 1 and 3 are two settings, a DT's file ignores the
    critics' fields) but the final evaluation's size (a curve reads the periodic ones). An older file's missing
    field counts at its default, which it ran with."""
    from minsubdt_jax.agents import AGENTS, result_fields
    from minsubdt_jax.methods import METHODS

    agents = {METHODS[m].agent for m in c["config"].get("method", default["method"]).split(",")}
    keys = sorted(frozenset({"env", "dataset"}).union(*(result_fields(a) for a in agents)) - {"eval_episodes"})
    revision = [c.get("dt_revision", 1)] if any(AGENTS[a].revision for a in agents) else []  # the model's code
    return json.dumps([c["dataset"]["sha256"]] + revision + [c["config"].get(k, default[k]) for k in keys])


def pooled(curves: dict) -> list[dict]:
    """Seeds of one configuration pooled across curve files (``--seed``: more seeds of a curve, their own file):
    per pool (files on the same data whose configs agree: :func:`pool_key`), method and evaluation step that
    every file of that method has, the mean and the std over all its seeds."""
    from minsubdt_jax.config import Config

    default = dataclasses.asdict(Config())
    pools = {}  # the shared config and the data's hash -> the files
    for name, c in curves.items():
        pools.setdefault(pool_key(c, default), []).append(name)
    rows = []
    for names in pools.values():
        if len(names) < 2:
            continue
        by = {}  # method -> {step: [seed means]}, seeds counted once
        for n in names:
            for m in curves[n]["models"]:
                if m["method"].endswith("(raw params)"):  # the averaged parameters only: the curves' own tables
                    continue                               # have the raw ones
                for step, v in zip(curves[n]["steps"], m["mean"]):
                    if np.isfinite(v):
                        by.setdefault(m["method"], {}).setdefault(step, {})[m["seed"]] = v
        for method, steps in by.items():
            most = max(len(v) for v in steps.values())
            for step in sorted(steps):
                v = np.array(list(steps[step].values()))
                if len(v) == most:
                    rows.append({"pool": " + ".join(sorted(names)), "method": method, "step": step, "seeds": len(v),
                                 "mean": float(v.mean()), "std": float(v.std(ddof=1)), "min": float(v.min()),
                                 "max": float(v.max())})
    return rows


def plot(curve: dict, png: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    steps = np.array(curve["steps"])
    for k, method in enumerate(dict.fromkeys(m["method"] for m in curve["models"])):
        ms = [m for m in curve["models"] if m["method"] == method]
        means = np.array([m["mean"] for m in ms])
        ls = "--" if method.endswith("(raw params)") else "-"
        for m in ms:
            ax.plot(steps, m["mean"], color=f"C{k}", alpha=0.3, lw=1, ls=ls)
        ax.errorbar(steps, means.mean(0), yerr=means.std(0, ddof=1) if len(ms) > 1 else None, color=f"C{k}", lw=2,
                    capsize=3, ls=ls, label=f"{method} (mean ± std over {len(ms)} seeds)")
    ds = curve["dataset"]
    ax.axhline(ds["normalized_score_mean"], color="gray", ls=":", label="dataset mean")
    c = curve["config"]
    ax.set(xlabel="gradient step", ylabel=f"normalised score ({curve['episodes'][-1]} episodes per seed)",
           title=f"{c['env']} {c['dataset']}: " + model_of(c).split(" (docs")[0].replace(" of the parameters", ""))
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, png, dpi=120)
    plt.close(fig)


def model_of(c: dict) -> str:
    """What trained: the DT's size and optimiser, or the critic agents at their references' settings."""
    from minsubdt_jax.agents import AGENTS
    from minsubdt_jax.methods import METHODS

    agents = sorted({METHODS[m].agent for m in c["method"].split(",")})
    if all(AGENTS[a].transitions for a in agents):
        return (f"{', '.join(agents)} at their references' settings (docs/critics.md), batch "
                f"{c.get('critic_batch_size', 256)} transitions")
    return (f"DT {c['embed_dim']}x{c['n_layers']}, K={c['context_len']}, lr {c['learning_rate']:g} "
            f"{c.get('lr_schedule', 'constant')}, warm-up {c['warmup_steps']}, batch {c['batch_size']}"
            + (f", EMA {c['ema_decay']:g} of the parameters" if c.get("ema_decay") else ""))


def report() -> str:
    """``experiments/results/curves.md``: every curve's table and its noise."""
    lines = ["# Score curves", "",
             "Made by `python experiments/curves.py report` from `experiments/results/curves/*.json`;",
             "each file names the command that trained it. Scores are normalised (brax dynamics: our references).", ""]
    files = sorted(fn for fn in (os.listdir(RESULTS) if os.path.isdir(RESULTS) else []) if fn.endswith(".json"))
    curves = {}
    for fn in files:
        with open(os.path.join(RESULTS, fn)) as f:
            curves[fn[:-5]] = json.load(f)
    pool = pooled(curves)
    if pool:
        lines += ["## Seeds pooled across files", "",
                  "Curves of one configuration run as several files (more seeds with `--seed`): at each step that "
                  "every seed of a method reached, the mean ± std over all its seeds (each seed: the mean over its "
                  "episodes).", "", "| curves | method | step | seeds | mean ± std | min – max |", "|---|---|---|---|---|---|"]
        lines += [f"| {r['pool']} | {r['method']} | {r['step']} | {r['seeds']} | {r['mean']:.1f} ± {r['std']:.1f} | "
                  f"{r['min']:.1f} – {r['max']:.1f} |" for r in pool]
        lines.append("")
    for fn in files:
        curve = curves[fn[:-5]]
        c, ds = curve["config"], curve["dataset"]
        lines += [f"## {fn[:-5]}", "", f"![curve](curves/{fn[:-5]}.png)", ""]
        if curve.get("partial"):
            lines += [f"**Partial: the run stopped at step {curve['steps'][-1]} of {c['steps']}**; the command below "
                      "resumes it from its last checkpoint (in `runs/curves/`, on the machine that ran it) or, "
                      "elsewhere, runs it again.", ""]
        lines += [
                  f"`{curve['command']}`; data `{os.path.basename(ds['path'])}` (sha256 {ds['sha256'][:12]}, "
                  f"{ds['episodes']} episodes, {ds['transitions']} transitions, normalised "
                  f"{ds['normalized_score_mean']:.1f}); {model_of(c)}; physics "
                  f"{(curve.get('physics') or {}).get('physics')}"
                  + (f"; trained on {pf['backend']}: {pf['device']} ({curve['train_seconds']:.0f} s of training "
                     "steps)" if (pf := curve.get("platform") or {}).get("backend", "cpu") != "cpu" else "") + ".",
                  "", "| method | step | seeds x episodes | mean | std between seeds | SE of one seed (episodes) | "
                  "seeds for ±3 points |", "|---|---|---|---|---|---|---|"]
        lines += [f"| {r['method']} | {r['step']} | {r['seeds']} x {r['episodes']} | {r['mean']:.1f} | "
                  f"{r['between_seeds_std']:.1f} | {r['episode_se']:.1f} | {r['seeds_for_3_points']} |"
                  for r in noise(curve)]
        st = stability(curve)
        if st:
            lines += ["", "Over the last third of the curve: how much one seed's score moves from checkpoint to checkpoint "
                      "(std over its evaluations, mean over seeds) against one evaluation's episode noise, and the "
                      "score averaged over those checkpoints per seed; the change over the third as the last "
                      "evaluation minus the first (3-seed means), and as a line fitted to every checkpoint of every "
                      "seed (`curves_report.trend`: one intercept per seed, ± its standard error). Flat: the fitted "
                      f"change is within ±{FLAT_POINTS:g} points (issue 25's criterion); unresolved: within, but its "
                      f"SE is above {UNRESOLVED_SE:g} points (`curves_report.flat_verdict`).", "",
                      "| method | evaluations (from step) | checkpoint-to-checkpoint std | episode SE | "
                      "last-third average, mean ± std over seeds | last minus first of the third | "
                      "fitted change ± SE | flat |", "|---|---|---|---|---|---|---|---|"]
            lines += [f"| {r['method']} | {r['evaluations']} (from {r['from_step']}) | {r['checkpoint_std']:.1f} | "
                      f"{r['episode_se']:.1f} | {r['last_third_mean']:.1f} ± {r['last_third_between_seeds']:.1f} | "
                      f"{r['first_to_last']:+.1f} | {r['fitted_change']:+.1f} ± {r['fitted_change_se']:.1f} | "
                      f"{flat_verdict(r['fitted_change'], r['fitted_change_se'])} |" for r in st]
        lines.append("")
    text = "\n".join(lines) + "\n"
    with atomic_open(os.path.join(HERE, "results", "curves.md")) as f:
        f.write(text)
    return text
